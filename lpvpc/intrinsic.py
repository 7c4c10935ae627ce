"""Intrinsic pathway: the LPV impulse-response regressor (eqs. 3-11)."""

from __future__ import annotations

import numpy as np

from .equations import lagged


def two_sided_lags(L: int):
    """Lags -L..L of the two-sided IRF (negative lags look into the future).

    >>> two_sided_lags(2)  # samples; negative lags look into the future
    [-2, -1, 0, 1, 2]
    """
    return list(range(-int(L), int(L) + 1))


def intrinsic_regressor(position, rho_basis, lags):
    """Psi_i (eq. 11): row k is P(k) kron G_i(rho(k)), column ``l * n_i + j``; ``position``
    in rad (N,), ``rho_basis`` the (N, n_i) scheduling basis values, ``lags`` in samples.

    With theta_i = H.ravel() (H of shape (n_lags, n_i), N m/rad) Psi_i @ theta_i equals
    :func:`lpvpc.equations.intrinsic_torque` (N m).

    >>> from lpvpc.equations import intrinsic_torque
    >>> rng = np.random.default_rng(0)
    >>> pos, G, H = rng.standard_normal(50), rng.standard_normal((50, 2)), rng.standard_normal((3, 2))
    >>> lags = two_sided_lags(1)
    >>> bool(np.allclose(intrinsic_regressor(pos, G, lags) @ H.ravel(), intrinsic_torque(lagged(pos, lags), G, H)))
    True
    """
    P = lagged(position, lags)
    n, n_i = rho_basis.shape
    return (P[:, :, None] * rho_basis[:, None, :]).reshape(n, len(lags) * n_i)
