"""Basis expansions in one variable (scheduling variable or delayed velocity).

The same code evaluates numpy arrays (column vectors of samples) and CasADi symbols, so
the numpy prediction and the exported CasADi/FMU step use one definition of the basis.

A basis is defined on the range ``[lo, hi]`` seen during identification. Outside it,
polynomials are never evaluated (a degree-7 polynomial at 1.3x its range explodes):
``extrapolation="clip"`` holds the value at the boundary; ``"linear"`` continues each
function along its tangent at the boundary (used for velocity, where a reflex
nonlinearity keeps growing with velocity but must not turn an outlier into a spike).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

FAMILIES = ("chebyshev", "legendre", "gaussian", "hinge")
EXTRAPOLATIONS = ("clip", "linear")


class NumpyOps:
    """Array operations used by model equations, numpy flavour (arrays of shape (N, k)).

    >>> NUMPY.row_sum(NUMPY.mtimes(np.ones((3, 2)), np.eye(2)))
    array([2., 2., 2.])
    """

    name = "numpy"

    @staticmethod
    def fmin(a, b):
        return np.minimum(a, b)

    @staticmethod
    def fmax(a, b):
        return np.maximum(a, b)

    @staticmethod
    def hcat(cols):
        return np.column_stack(cols)

    @staticmethod
    def row_sum(a):
        return np.sum(a, axis=1)

    @staticmethod
    def exp(a):
        return np.exp(a)

    @staticmethod
    def mtimes(a, b):
        return a @ b


class CasadiOps:
    """The same operations on CasADi SX/MX row vectors (one sample, shape (1, k)).

    The same expression on a CasADi symbol (one sample) gives the numpy value when evaluated:

    >>> import casadi as ca
    >>> x = ca.SX.sym("x")
    >>> b = Basis("chebyshev", 3, -0.4, 0.2)
    >>> row = b.evaluate(x, CasadiOps())
    >>> f = ca.Function("f", [x], [row])
    >>> bool(np.allclose(np.array(f(0.1)), b.evaluate([0.1])))
    True
    """

    name = "casadi"

    def __init__(self):
        import casadi as ca

        self.ca = ca

    def fmin(self, a, b):
        return self.ca.fmin(a, b)

    def fmax(self, a, b):
        return self.ca.fmax(a, b)

    def hcat(self, cols):
        return self.ca.horzcat(*cols)

    def row_sum(self, a):
        return self.ca.sum2(a)

    def exp(self, a):
        return self.ca.exp(a)

    def mtimes(self, a, b):
        return self.ca.mtimes(a, self.ca.DM(b) if isinstance(b, np.ndarray) else b)


NUMPY = NumpyOps()


@dataclass(frozen=True)
class Basis:
    """``order + 1`` functions of one variable on the identified range ``[lo, hi]``.

    chebyshev/legendre: polynomials T_0..T_order of the variable mapped to [-1, 1].
    gaussian: a constant plus ``order`` Gaussian bumps evenly spaced over the range.
    hinge: 1, s and ``order - 1`` ramps max(s - knot, 0), knots denser near s = 0
    (continuous piecewise-linear functions: a rectifier's kink is representable, and
    the functions are linear beyond the range).

    Parameters
    ----------
    family : {"chebyshev", "legendre", "gaussian", "hinge"}
        The basis family (above).
    order : int
        Its order: ``order + 1`` functions.
    lo, hi : float
        The identified range of the variable.
    extrapolation : {"clip", "linear"}, default "clip"
        Beyond the range the functions are held at the edge value, or continued along their
        tangent (the gaussian family: "clip" only; another value raises ValueError).

    Examples
    --------
    A cubic Chebyshev basis of the scheduling angle (rad) identified on [-0.4, 0.2] rad:
    inside the range its functions are the polynomials, outside they hold the edge value.

    >>> b = Basis("chebyshev", 3, lo=-0.4, hi=0.2)
    >>> b.size
    4
    >>> b.evaluate([-0.4, -0.1, 0.2]).round(3)
    array([[ 1., -1.,  1., -1.],
           [ 1.,  0., -1., -0.],
           [ 1.,  1.,  1.,  1.]])
    >>> bool(np.array_equal(b.evaluate([0.5]), b.evaluate([0.2])))  # clipped beyond hi
    True
    >>> Basis.from_dict(b.to_dict()) == b
    True
    """

    family: str
    order: int
    lo: float
    hi: float
    extrapolation: str = "clip"

    def __post_init__(self):
        if self.family not in FAMILIES:
            raise ValueError(f"unknown basis family {self.family!r}; choose one of {FAMILIES}")
        if self.extrapolation not in EXTRAPOLATIONS:
            raise ValueError(f"unknown extrapolation {self.extrapolation!r}; choose one of {EXTRAPOLATIONS}")
        if int(self.order) != self.order or self.order < 0:
            raise ValueError(f"basis order must be a non-negative integer, got {self.order!r}")
        if not (np.isfinite(self.lo) and np.isfinite(self.hi) and self.hi > self.lo):
            raise ValueError(f"basis range must satisfy lo < hi, got [{self.lo}, {self.hi}]")
        if self.family == "gaussian" and self.extrapolation == "linear":
            raise ValueError("gaussian basis supports only extrapolation='clip'")

    @property
    def size(self) -> int:
        return self.order + 1

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Basis":
        return cls(**d)

    # -- evaluation -------------------------------------------------------------------
    def normalise(self, x):
        """Map [lo, hi] to [-1, 1]."""
        return (2.0 * x - (self.hi + self.lo)) / (self.hi - self.lo)

    def evaluate(self, x, ops=NUMPY):
        """Basis functions at ``x``.

        numpy: ``x`` of shape (N,) gives an (N, size) array. CasADi: a scalar symbol gives
        a (1, size) row.
        """
        if ops is NUMPY:
            x = np.asarray(x, dtype=float).reshape(-1, 1)
        s = self.normalise(x)
        sc = ops.fmax(ops.fmin(s, 1.0), -1.0)
        values = self._functions(sc, ops)
        if self.extrapolation == "clip":
            return ops.hcat(values)
        # Tangent continuation: f(s) = f(+-1) + f'(+-1) * (s -+ 1) outside [-1, 1].
        above = ops.fmax(s - 1.0, 0.0)
        below = ops.fmin(s + 1.0, 0.0)
        d_hi, d_lo = self._edge_slopes()
        return ops.hcat([v + above * dh + below * dl for v, dh, dl in zip(values, d_hi, d_lo)])

    def _functions(self, s, ops):
        n = self.order
        if self.family == "hinge":
            return [s * 0.0 + 1.0] + ([s] if n >= 1 else []) + [ops.fmax(s - k, 0.0) for k in self.knots()]
        if self.family == "gaussian":
            centres = np.linspace(-1.0, 1.0, n) if n > 1 else np.array([0.0])
            width = 2.0 / max(n - 1, 1)
            return [s * 0.0 + 1.0] + [ops.exp(-0.5 * ((s - c) / width) ** 2) for c in centres[:n]]
        values = [s * 0.0 + 1.0]
        if n >= 1:
            values.append(s)
        for k in range(1, n):
            if self.family == "chebyshev":
                values.append(2.0 * s * values[k] - values[k - 1])
            else:  # Legendre: (k+1) P_{k+1} = (2k+1) s P_k - k P_{k-1}
                values.append(((2 * k + 1) * s * values[k] - k * values[k - 1]) / (k + 1))
        return values

    def knots(self):
        """Hinge knots in normalised units: sign(u) u^2 for u evenly spaced inside (-1, 1)."""
        u = np.linspace(-1.0, 1.0, self.order + 1)[1:-1]
        return np.sign(u) * u**2

    def _edge_slopes(self):
        """Derivatives of each function (in normalised units) at s = +1 and s = -1."""
        if self.family == "hinge":
            ramps = max(self.order - 1, 0)
            d_hi = np.array([0.0] + [1.0] * (self.order >= 1) + [1.0] * ramps)
            d_lo = np.array([0.0] + [1.0] * (self.order >= 1) + [0.0] * ramps)
            return d_hi, d_lo
        k = np.arange(self.order + 1, dtype=float)
        if self.family == "chebyshev":
            d_hi = k**2
        else:
            d_hi = k * (k + 1) / 2.0
        d_lo = d_hi * (-1.0) ** (k + 1)
        return d_hi, d_lo


def basis_from_data(x, family: str, order: int, extrapolation: str = "clip") -> Basis:
    """A basis spanning the range of ``x`` (the identification data).

    >>> vel = np.linspace(-1.5, 2.0, 50)  # rad/s
    >>> b = basis_from_data(vel, "hinge", 4, extrapolation="linear")
    >>> (b.lo, b.hi)
    (-1.5, 2.0)
    >>> float(b.evaluate([3.0])[0, 1])  # linear beyond the range: s = 1.57 at 3 rad/s
    1.5714285714285714
    """
    x = np.asarray(x, dtype=float)
    lo, hi = float(np.min(x)), float(np.max(x))
    if hi - lo < 1e-9:
        hi = lo + 1e-9
    return Basis(family=family, order=int(order), lo=lo, hi=hi, extrapolation=extrapolation)
