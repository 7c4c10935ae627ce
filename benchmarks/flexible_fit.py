"""A crude flexible least-squares model: the simple alternative the real-data benchmarks
compare the package with.

Unstructured LPV FIR: torque(k) = sum_l h_l(rho) pos(k - l) (lags -L..L) + sum_j
g_j(vel(k - j), rho) (reflex lags j = delay..delay + n_reflex - 1, g a hinge basis in
velocity times a Chebyshev basis in rho) + c, one least-squares solve, no structure (no
Hammerstein rank constraint, no state-space reflex dynamics). Bases are fitted on the
identification part and clipped (rho) or continued linearly (velocity) beyond it, like the
package's. Units: rad, rad/s, N m, s.
"""

from __future__ import annotations

import numpy as np

from lpvpc.models import equations as eq
from lpvpc.models.basis import basis_from_data


class FlexibleFit:
    def __init__(self, fs, irf_length=0.04, reflex_delay=0.04, reflex_length=0.31, rho_order=5, reflex_rho_order=2,
                 velocity_order=6):
        self.fs = float(fs)
        self.L = int(round(irf_length * fs))
        self.delay = int(round(reflex_delay * fs))
        self.n_reflex = int(round(reflex_length * fs))
        self.orders = (rho_order, reflex_rho_order, velocity_order)

    def _features(self, p, rho):
        Gi, Gr = self.Gi.evaluate(rho), self.Gr.evaluate(rho)
        P = eq.lagged(p, list(range(-self.L, self.L + 1)))
        cols = [(P[:, :, None] * Gi[:, None, :]).reshape(len(p), -1)]
        V = self.Vb.evaluate(eq.velocity(p, self.fs))
        for j in range(self.delay, self.delay + self.n_reflex):
            Vj = np.column_stack([eq.lagged(V[:, i], [j])[:, 0] for i in range(V.shape[1])])
            cols.append((Vj[:, :, None] * Gr[:, None, :]).reshape(len(p), -1))
        cols.append(np.ones((len(p), 1)))
        return np.hstack(cols)

    def fit(self, p, y, rho):
        ro, rro, vo = self.orders
        stationary = np.ptp(rho) < 0.01
        self.Gi = basis_from_data(rho, "chebyshev", 0 if stationary else ro)
        self.Gr = basis_from_data(rho, "chebyshev", 0 if stationary else rro)
        self.Vb = basis_from_data(eq.velocity(p, self.fs), "hinge", vo, extrapolation="linear")
        X = self._features(p, rho)
        self.theta, *_ = np.linalg.lstsq(X, y, rcond=None)
        self.n_params = X.shape[1]
        return self

    def predict(self, p, rho):
        return self._features(p, rho) @ self.theta
