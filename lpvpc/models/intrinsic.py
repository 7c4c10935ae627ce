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
    :func:`lpvpc.models.equations.intrinsic_torque` (N m).

    >>> from lpvpc.models.equations import intrinsic_torque
    >>> rng = np.random.default_rng(0)
    >>> pos, G, H = rng.standard_normal(50), rng.standard_normal((50, 2)), rng.standard_normal((3, 2))
    >>> lags = two_sided_lags(1)
    >>> bool(np.allclose(intrinsic_regressor(pos, G, lags) @ H.ravel(), intrinsic_torque(lagged(pos, lags), G, H)))
    True
    """
    P = lagged(position, lags)
    n, n_i = rho_basis.shape
    return (P[:, :, None] * rho_basis[:, None, :]).reshape(n, len(lags) * n_i)


def derivative_matrix(basis) -> np.ndarray:
    """Dm (n_i, n_i) with G_i'(rho) = G_i(rho) Dm over the basis range: a weight vector s
    has d/drho [G_i(rho) . s] = G_i(rho) . (Dm s). Exact for polynomial bases (the derivative
    of an order-n polynomial is one of order n - 1); least squares over the range otherwise.

    >>> from lpvpc.models.basis import Basis
    >>> b = Basis("chebyshev", 3, -0.4, 0.2)
    >>> x = np.linspace(-0.35, 0.15, 7)  # rad, inside the range (the basis is held beyond it)
    >>> s = np.array([1.0, -2.0, 0.5, 3.0])
    >>> h = 1e-6
    >>> slope = (b.evaluate(x + h) - b.evaluate(x - h)) @ s / (2 * h)
    >>> bool(np.allclose(b.evaluate(x) @ (derivative_matrix(b) @ s), slope, atol=1e-4))
    True
    """
    x = np.linspace(basis.lo, basis.hi, 8 * basis.size + 16)
    h = 1e-6 * (basis.hi - basis.lo)
    inner = x[1:-1]  # central differences inside the range (the basis is held constant outside)
    dG = (basis.evaluate(inner + h) - basis.evaluate(inner - h)) / (2 * h)
    return np.linalg.lstsq(basis.evaluate(inner), dG, rcond=None)[0]


def curvature_from_irf(H, basis) -> np.ndarray:
    """Elastic curvature coefficients c (N m/rad^2) tied to the IRF: G_i(rho) . c =
    0.5 K'(rho), with K(rho) = G_i(rho) . sum_l H[l] the IRF's stiffness (N m/rad).

    An IRF whose stiffness rises by 100 N m/rad per rad has a curvature of 50 N m/rad^2:

    >>> from lpvpc.models.basis import Basis
    >>> b = Basis("chebyshev", 1, -0.4, 0.2)  # 1 and s, linear in rho over [-0.4, 0.2] rad
    >>> H = np.array([[40.0, 0.0], [10.0, 30.0]])  # two lags; K = 50 + 30 s: slope 30 / 0.3 rad
    >>> round(float((b.evaluate([0.0]) @ curvature_from_irf(H, b))[0]), 6)  # N m/rad^2
    50.0
    """
    return 0.5 * derivative_matrix(basis) @ np.asarray(H, dtype=float).sum(axis=0)


def curvature_regressor(position, rho_basis, basis) -> np.ndarray:
    """The elastic curvature term's share of each IRF column, (N, n_i), the same for every
    lag: with the curvature tied to the IRF (:func:`curvature_from_irf`), the intrinsic torque
    is ``(Psi_i + tile(curvature_regressor, n_lags)) @ H.ravel()``: column j is
    0.5 pos(k)^2 [G_i(rho(k)) Dm]_j, the same for every lag.

    >>> from lpvpc.models.basis import Basis
    >>> from lpvpc.models.equations import elastic_curvature_torque
    >>> b = Basis("chebyshev", 2, -0.4, 0.2)
    >>> rng = np.random.default_rng(0)
    >>> pos, rho, H = 0.04 * rng.standard_normal(50), rng.uniform(-0.4, 0.2, 50), rng.standard_normal((3, 3))
    >>> G = b.evaluate(rho)
    >>> tied = curvature_regressor(pos, G, b) @ H.sum(axis=0)
    >>> bool(np.allclose(tied, elastic_curvature_torque(pos, G, curvature_from_irf(H, b))))
    True
    """
    position = np.asarray(position, dtype=float)
    return 0.5 * (position * position)[:, None] * (rho_basis @ derivative_matrix(basis))
