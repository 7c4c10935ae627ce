"""The virtual subject's parameters and curves: :class:`SubjectParams` (stiffness K(theta),
elastic torque, reflex gain and threshold), the simulation rate and the paper's
identification range.

Units are SI: angle rad (positive = dorsiflexion), torque N m, stiffness N m/rad, viscosity
N m s/rad, inertia kg m^2. Used by every element of the simulation (:mod:`lpvpc.simulation.simulate`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np


FS_SIM = 1000.0  # Hz: the rate of the continuous-time physics (and of the lab's A/D)

# The identification range of the paper's multilevel trajectory.
THETA_PF = -0.4  # rad, most plantarflexed level
THETA_DF = 0.2  # rad, most dorsiflexed level

_EXP_MAX = 700.0  # keeps np.exp finite for absurd angles (no overflow warnings)

#: Elastic stiffness families of the virtual subject (SubjectParams.stiffness_family):
#: "standard" (today's smooth sum of exponentials, which the position basis holds to < 0.5 %
#: at order 4), "sum_of_exponentials" (the textbook form with steeper ends: a Chebyshev basis of
#: order 4-5 misses it by 5-7 % over the central 80 % of the range) and "piecewise"
#: (piecewise-linear K with a kink near its minimum: 20-35 % at orders 4-7) and "polynomial"
#: (a polynomial in theta, ``k_poly``: a smooth curve with other curvature than an exponential's).
STIFFNESS_FAMILIES = ("standard", "sum_of_exponentials", "piecewise", "polynomial")

#: The textbook sum of exponentials (k_base, k_df, k_df_rate, k_pf, k_pf_rate): 20 N m/rad
#: plus 160 N m/rad at +0.2 rad decaying at 14/rad and 45 N m/rad at -0.4 rad decaying at
#: 18/rad (K 22..180 N m/rad, minimum near -0.14 rad).
SUM_OF_EXPONENTIALS = {"k_base": 20.0, "k_df": 160.0, "k_df_rate": 14.0, "k_pf": 45.0, "k_pf_rate": 18.0}


def _exp(x):
    return np.exp(np.clip(x, -_EXP_MAX, _EXP_MAX))


# ---------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------


@dataclass
class SubjectParams:
    """Physical parameters of the virtual ankle, the actuator and the torque sensor.

    Elastic stiffness (exponential-type, smooth, not a polynomial)::

        K(theta) = k_base + k_df * exp(k_df_rate * (theta - theta_df))
                          + k_pf * exp(-k_pf_rate * (theta - theta_pf))

    rises steeply toward dorsiflexion (~150 N m/rad at +0.2 rad), has its minimum
    (~33 N m/rad) near -0.26 rad, between neutral and full plantarflexion, and rises again
    somewhat toward -0.4 rad (~40 N m/rad): passive tissue stretch of the plantarflexors
    (dorsiflexion) and of the anterior structures (plantarflexion).
    ``elastic_torque`` is its exact integral, zero at ``elastic_rest``.

    ``stiffness_family`` (:data:`STIFFNESS_FAMILIES`) picks the shape of K(theta); build
    another family with :meth:`with_stiffness_family` (it sets that family's values).
    "piecewise" is linear between ``k_knots`` (rad) with values ``k_values`` (N m/rad),
    continued linearly beyond the end knots; its elastic torque (piecewise quadratic) is
    continuous. "polynomial" is K(theta) = sum_i k_poly[i] theta^i (its default
    30 + 500 (theta + 0.2)^2 + 625 (theta + 0.2)^3 N m/rad: 45 at -0.4 rad, minimum 30 at
    -0.2 rad, 150 at +0.2 rad).

    Reflex nonlinearity: half-wave rectifier of delayed velocity with gain ``G(theta)``
    (exponential from ``reflex_gain_pf`` at theta_pf to ``reflex_gain_df`` at theta_df)
    and threshold ``th(theta)`` (linear from ``reflex_threshold_pf`` to
    ``reflex_threshold_df``, floored at ``reflex_threshold_min``).

    Parameters
    ----------
    inertia : float, default 0.015
        kg m^2, foot + pedal moment of inertia.
    viscosity : float, default 0.7
        N m s/rad, intrinsic viscosity B.
    k_base : float, default 25.0
        N m/rad, constant part of K(theta).
    k_df : float, default 125.0
        N m/rad, dorsiflexion exponential's value at theta_df.
    k_df_rate : float, default 7.0
        1/rad, its growth rate toward dorsiflexion.
    k_pf : float, default 15.0
        N m/rad, plantarflexion exponential's value at theta_pf.
    k_pf_rate : float, default 12.0
        1/rad, its growth rate toward plantarflexion.
    theta_df : float, default 0.2
        rad, reference angle of the dorsiflexion end.
    theta_pf : float, default -0.4
        rad, reference angle of the plantarflexion end.
    elastic_rest : float, default -0.2
        rad, angle where the elastic torque is zero (passive rest).
    stiffness_family : str, default "standard"
        Shape of K(theta): one of STIFFNESS_FAMILIES.
    k_knots : tuple of float, optional
        rad, knots of the "piecewise" K (the kink at -0.15); default (-0.4, -0.15, 0.2).
    k_values : tuple of float, optional
        N m/rad, the "piecewise" K at its knots; default (45.0, 25.0, 150.0).
    k_poly : tuple of float, optional
        N m/rad/rad^i, the "polynomial" K's coefficients of theta^i; default (55.0, 275.0,
        875.0, 625.0).
    reflex_delay : float, default 0.040
        s, stretch-reflex loop delay.
    reflex_gain_pf : float, default 2.0
        N m s/rad, rectifier slope at theta_pf.
    reflex_gain_df : float, default 8.0
        N m s/rad, rectifier slope at theta_df.
    reflex_threshold_pf : float, default 0.7
        rad/s, velocity threshold at theta_pf.
    reflex_threshold_df : float, default 0.25
        rad/s, velocity threshold at theta_df.
    reflex_threshold_min : float, default 0.05
        rad/s, floor when extrapolating far into DF.
    reflex_wn : float, default 16.0
        rad/s, natural frequency of the reflex low-pass (activation dynamics).
    reflex_zeta : float, default 0.65
        1, damping of the reflex low-pass (unit DC gain).
    servo_wn : float, optional
        rad/s (25 Hz): closed-loop natural frequency; default 2 pi x 25 Hz.
    servo_zeta : float, default 0.7
        1, closed-loop damping.
    emg_tonic : float, default 0.08
        1, tonic (background) activation present in both trials.
    emg_reflex_torque : float, default 15.0
        N m of reflex drive per unit of reflex-evoked activation.
    emg_volts : float, default 300e-6
        V of envelope at full activation (1.0).
    emg_noise : float, default 0.015
        1, RMS of the envelope's measurement noise (activation units).
    emg_cutoff : float, default 30.0
        Hz, envelope low-pass (rectify, then 2nd-order Butterworth).
    emg_band : tuple of float, optional
        Hz, band of the raw surface EMG (the noise carrier the drive modulates); default (20.0,
        450.0).
    emg_form : str, default "modulated_noise"
        How the envelope is made: one of lpvpc.simulation.emg.EMG_FORMS.
    emg_offset : float, default 0.0
        1, constant offset of the "envelope" form (amplifier / rectifier offset).
    activation_cutoff : float, default 0.05
        Hz, how fast a(t) varies (2nd-order low-pass of the noise behind it).
    activation_shared : bool, default False
        True: the same a(t) in PT and UT (a real pair is recorded at two times).
    activation_stiffness_gain : float, default 1.0
        Background_activation: perturbation K, B scaled by 1 + this * a.
    activation_reflex_gain : float, default 1.0
        Background_activation: reflex gain scaled by 1 + this * a.
    noise_cutoff : float, default 20.0
        Hz, cut-off of the 2nd-order Butterworth that colours the noise.
    noise_order : int, default 2
        Order of that filter.
    """

    # intrinsic mechanics
    inertia: float = 0.015  # kg m^2, foot + pedal moment of inertia
    viscosity: float = 0.7  # N m s/rad, intrinsic viscosity B
    k_base: float = 25.0  # N m/rad, constant part of K(theta)
    k_df: float = 125.0  # N m/rad, dorsiflexion exponential's value at theta_df
    k_df_rate: float = 7.0  # 1/rad, its growth rate toward dorsiflexion
    k_pf: float = 15.0  # N m/rad, plantarflexion exponential's value at theta_pf
    k_pf_rate: float = 12.0  # 1/rad, its growth rate toward plantarflexion
    theta_df: float = THETA_DF  # rad, reference angle of the dorsiflexion end
    theta_pf: float = THETA_PF  # rad, reference angle of the plantarflexion end
    elastic_rest: float = -0.2  # rad, angle where the elastic torque is zero (passive rest)
    stiffness_family: str = "standard"  # shape of K(theta): one of STIFFNESS_FAMILIES
    k_knots: tuple = (-0.4, -0.15, 0.2)  # rad, knots of the "piecewise" K (the kink at -0.15)
    k_values: tuple = (45.0, 25.0, 150.0)  # N m/rad, the "piecewise" K at its knots
    k_poly: tuple = (55.0, 275.0, 875.0, 625.0)  # N m/rad/rad^i, the "polynomial" K's coefficients of theta^i
    # reflex pathway
    reflex_delay: float = 0.040  # s, stretch-reflex loop delay
    reflex_gain_pf: float = 2.0  # N m s/rad, rectifier slope at theta_pf
    reflex_gain_df: float = 8.0  # N m s/rad, rectifier slope at theta_df
    reflex_threshold_pf: float = 0.7  # rad/s, velocity threshold at theta_pf
    reflex_threshold_df: float = 0.25  # rad/s, velocity threshold at theta_df
    reflex_threshold_min: float = 0.05  # rad/s, floor when extrapolating far into DF
    reflex_wn: float = 16.0  # rad/s, natural frequency of the reflex low-pass (activation dynamics)
    reflex_zeta: float = 0.65  # 1, damping of the reflex low-pass (unit DC gain)
    # actuator: a stiff hydraulic position servo
    servo_wn: float = 2 * math.pi * 25.0  # rad/s (25 Hz): closed-loop natural frequency
    servo_zeta: float = 0.7  # 1, closed-loop damping
    # EMG (a rectified, smoothed envelope of the plantarflexors' surface EMG, as the lab records it)
    emg_tonic: float = 0.08  # 1, tonic (background) activation present in both trials
    emg_reflex_torque: float = 15.0  # N m of reflex drive per unit of reflex-evoked activation
    emg_volts: float = 300e-6  # V of envelope at full activation (1.0)
    emg_noise: float = 0.015  # 1, RMS of the envelope's measurement noise (activation units)
    emg_cutoff: float = 30.0  # Hz, envelope low-pass (rectify, then 2nd-order Butterworth)
    emg_band: tuple = (20.0, 450.0)  # Hz, band of the raw surface EMG (the noise carrier the drive modulates)
    emg_form: str = "modulated_noise"  # how the envelope is made: one of lpvpc.simulation.emg.EMG_FORMS
    emg_offset: float = 0.0  # 1, constant offset of the "envelope" form (amplifier / rectifier offset)
    # background activation a(t) of the activation effects (its own slow dynamics, not the reflex's)
    activation_cutoff: float = 0.05  # Hz, how fast a(t) varies (2nd-order low-pass of the noise behind it)
    activation_shared: bool = False  # True: the same a(t) in PT and UT (a real pair is recorded at two times)
    activation_stiffness_gain: float = 1.0  # background_activation: perturbation K, B scaled by 1 + this * a
    activation_reflex_gain: float = 1.0  # background_activation: reflex gain scaled by 1 + this * a
    # torque sensor / background noise
    noise_cutoff: float = 20.0  # Hz, cut-off of the 2nd-order Butterworth that colours the noise
    noise_order: int = 2  # order of that filter

    # -- intrinsic --------------------------------------------------------------------
    def with_stiffness_family(self, family: str) -> "SubjectParams":
        """A copy with the elastic stiffness of ``family`` (:data:`STIFFNESS_FAMILIES`);
        "sum_of_exponentials" sets :data:`SUM_OF_EXPONENTIALS`, "standard" the defaults'
        values; every other parameter is kept (examples: tests/test_simulate.py, whose
        example of SubjectParams is registered in tests/test_examples.py)."""
        if family not in STIFFNESS_FAMILIES:
            raise ValueError(f"unknown stiffness family {family!r}; use one of {list(STIFFNESS_FAMILIES)}")
        d = SubjectParams()
        values = {k: getattr(d, k) for k in SUM_OF_EXPONENTIALS}
        if family == "sum_of_exponentials":
            values = dict(SUM_OF_EXPONENTIALS)
        return replace(self, stiffness_family=family, **values)

    def _check_family(self):
        if self.stiffness_family not in STIFFNESS_FAMILIES:
            raise ValueError(f"unknown stiffness family {self.stiffness_family!r}; use one of "
                             f"{list(STIFFNESS_FAMILIES)}")
        if self.stiffness_family == "piecewise":
            x = np.asarray(self.k_knots, dtype=float)
            if len(x) < 2 or len(x) != len(self.k_values) or np.any(np.diff(x) <= 0):
                raise ValueError("piecewise stiffness needs >= 2 increasing k_knots and as many k_values")
        if self.stiffness_family == "polynomial" and len(self.k_poly) < 1:
            raise ValueError("polynomial stiffness needs at least one coefficient in k_poly")

    def _polynomial(self, theta):
        """(K, integral of K from 0) of the polynomial family at ``theta``."""
        c = np.asarray(self.k_poly, dtype=float)
        K = np.polynomial.polynomial.polyval(theta, c)
        E = np.polynomial.polynomial.polyval(theta, np.concatenate([[0.0], c / np.arange(1, len(c) + 1)]))
        return K, E

    def _piecewise(self, theta):
        """(K, integral of K from the first knot) of the piecewise-linear family at ``theta``."""
        x, k = np.asarray(self.k_knots, dtype=float), np.asarray(self.k_values, dtype=float)
        slope = np.diff(k) / np.diff(x)
        at_knot = np.concatenate([[0.0], np.cumsum(np.diff(x) * (k[:-1] + 0.5 * slope * np.diff(x)))])
        i = np.clip(np.searchsorted(x, theta, side="right") - 1, 0, len(x) - 2)  # end segments continue
        u = theta - x[i]
        return k[i] + slope[i] * u, at_knot[i] + k[i] * u + 0.5 * slope[i] * u * u

    def K(self, theta):
        """Elastic stiffness dE/dtheta (N m/rad) at joint angle ``theta`` (rad)."""
        theta = np.asarray(theta, dtype=float)
        self._check_family()
        if self.stiffness_family == "piecewise":
            return self._piecewise(theta)[0]
        if self.stiffness_family == "polynomial":
            return self._polynomial(theta)[0]
        return (
            self.k_base
            + self.k_df * _exp(self.k_df_rate * (theta - self.theta_df))
            + self.k_pf * _exp(-self.k_pf_rate * (theta - self.theta_pf))
        )

    def incremental_stiffness(self, theta, amplitude: float = 0.04):
        """Stiffness (N m/rad) a linear model sees at ``theta`` (rad) under perturbations
        uniform in +-``amplitude`` rad (the PRALDS levels): the least-squares slope of
        E(theta + s) - E(theta) on s, 3/(2 a^3) int_{-a}^{a} s (E(theta + s) - E(theta)) ds.

        The elastic curve is nonlinear within a perturbation (its dorsiflexion exponential
        changes by e^{+-0.28} over +-0.04 rad), so this is what any linear identification
        estimates; it exceeds the tangent K(theta) by 0.3-0.6 % at 0.04 rad. Exactly: each
        exponential term c e^{r u} becomes c e^{r u} phi(r a), phi(x) = 3 (x cosh x - sinh x) / x^3
        = 1 + x^2/10 + ... (and ``amplitude`` -> 0 gives K).
        """
        theta = np.asarray(theta, dtype=float)
        self._check_family()
        if self.stiffness_family in ("piecewise", "polynomial"):  # Gauss-Legendre over s in +-amplitude
            if amplitude <= 0:
                return self.K(theta)
            s, w = np.polynomial.legendre.leggauss(400)
            s, w = amplitude * s, amplitude * w
            dE = self.elastic_torque(theta[..., None] + s) - self.elastic_torque(theta)[..., None]
            return 1.5 / amplitude ** 3 * np.sum(w * s * dE, axis=-1)

        def phi(x):
            return 1.0 + x * x / 10.0 if x < 1e-3 else 3.0 * (x * np.cosh(x) - np.sinh(x)) / x**3

        return (
            self.k_base
            + self.k_df * _exp(self.k_df_rate * (theta - self.theta_df)) * phi(self.k_df_rate * amplitude)
            + self.k_pf * _exp(-self.k_pf_rate * (theta - self.theta_pf)) * phi(self.k_pf_rate * amplitude)
        )

    def _E_unshifted(self, theta):
        theta = np.asarray(theta, dtype=float)
        self._check_family()
        if self.stiffness_family == "piecewise":
            return self._piecewise(theta)[1]
        if self.stiffness_family == "polynomial":
            return self._polynomial(theta)[1]
        return (
            self.k_base * theta
            + self.k_df / self.k_df_rate * _exp(self.k_df_rate * (theta - self.theta_df))
            - self.k_pf / self.k_pf_rate * _exp(-self.k_pf_rate * (theta - self.theta_pf))
        )

    def elastic_torque(self, theta):
        """Elastic torque E(theta) (N m): the exact integral of K, zero at ``elastic_rest``."""
        return self._E_unshifted(theta) - self._E_unshifted(self.elastic_rest)

    # -- reflex -----------------------------------------------------------------------
    def _s(self, theta):
        # 0 at theta_pf, 1 at theta_df (extrapolates linearly outside)
        return (np.asarray(theta, dtype=float) - self.theta_pf) / (self.theta_df - self.theta_pf)

    def reflex_gain(self, theta):
        """Reflex rectifier slope G(theta) (N m s/rad): rises exponentially toward DF."""
        ratio = self.reflex_gain_df / self.reflex_gain_pf
        return self.reflex_gain_pf * _exp(np.log(ratio) * self._s(theta))

    def reflex_threshold(self, theta):
        """Reflex velocity threshold th(theta) (rad/s): falls linearly toward DF."""
        s = self._s(theta)
        th = self.reflex_threshold_pf + (self.reflex_threshold_df - self.reflex_threshold_pf) * s
        return np.maximum(th, self.reflex_threshold_min)

    def to_dict(self) -> dict:
        """Plain-float dictionary of all fields (JSON-serialisable)."""
        return {k: (float(v) if isinstance(v, float) else v) for k, v in asdict(self).items()}

    def curves(self, theta=None) -> dict:
        """K, elastic torque, reflex gain and threshold sampled on a theta grid (lists)."""
        if theta is None:
            theta = np.round(np.arange(-0.45, 0.2501, 0.01), 10)
        theta = np.asarray(theta, dtype=float)
        return {
            "theta": theta.tolist(),
            "K": self.K(theta).tolist(),
            "elastic_torque": self.elastic_torque(theta).tolist(),
            "reflex_gain": self.reflex_gain(theta).tolist(),
            "reflex_threshold": self.reflex_threshold(theta).tolist(),
        }
