"""MOESP subspace identification of (A, C) for the MISO form (21)-(23).

Past-output MOESP (PO-MOESP, Verhaegen 1994): the future outputs are projected onto the
past inputs and outputs after the future inputs are removed, and the extended
observability matrix is read off the SVD of that block. Past outputs as instruments are
robust on real data, where past-input-only instruments can lock onto slow drift.

Only the inputs that drive the state (the reflex inputs U_r) are used as past
instruments; the intrinsic inputs U_i reach the output only through D_tot (eq. 23) and
are removed as future inputs.

The block Hankel matrix (about ``2 s n_u`` rows by N columns) is never formed. MOESP
needs only its LQ factor L = R^T, and R is the Cholesky factor of the Gram matrix H^T H,
whose entries are lagged cross-products of the ~n_u base signals: one matrix product per
lag (2s of them, on N x n_u) instead of a QR of N x 2s n_u (``hankel_gram``; 2-3x
faster at N = 12,000: benchmarks/results/identify_floor.txt). Columns that repeat earlier ones (a constant basis function at
every shift, a lagged position seen at two shifts) are dependent: they get zero rows
(``lpvpc.linalg.deflated_cholesky``). Where that factor does not reproduce the Gram
matrix (squared conditioning: short records, whose scheduling takes few levels), the
transpose of H is streamed through a QR factorisation chunk by chunk instead
(``streamed_r``). Memory is O((s n_u)^2) plus a block of rows: the base signals are
scaled and stacked block by block (:class:`StackedColumns`), never as one N x n matrix
(a 30-minute record's subspace step took 595 MB above its inputs before, 6 MB now);
time is linear in N.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.signal

from ..models.equations import STABLE_POLE_RADIUS, companion_form  # noqa: F401
from ..errors import IdentificationError, InsufficientExcitationError
from ..linalg import CHUNK_ROWS, DEFLATE_TOL, deflated_cholesky, fold_rows, gram_factor_ok, orthonormal_range
from ..io.segments import Segments


@dataclass
class SubspaceResult:
    """Singular values of the projected future outputs and the observability basis.

    >>> rng = np.random.default_rng(0)
    >>> u = rng.standard_normal(2000)
    >>> y = scipy.signal.lfilter([0.0, 1.0], np.poly([0.9, 0.7]), u)  # poles 0.9 and 0.7
    >>> A, C = po_moesp(u[:, None], np.zeros((2000, 0)), y, horizon=6).system(2)
    >>> np.sort(np.linalg.eigvals(A).real).round(6)
    array([0.7, 0.9])
    """

    singular_values: np.ndarray
    left_vectors: np.ndarray  # (s, s) left singular vectors
    horizon: int
    factorisation: str = "gram"  # how the LQ factor was had: "gram" (Cholesky) or "qr"

    def system(self, order: int):
        """(A, C) of the given state order from the shift invariance of Gamma_s."""
        if not 1 <= order < self.horizon:
            raise IdentificationError(f"state order {order} must be between 1 and horizon-1 = {self.horizon - 1}")
        gamma = self.left_vectors[:, :order] * np.sqrt(self.singular_values[:order])
        A = np.linalg.lstsq(gamma[:-1], gamma[1:], rcond=None)[0]
        C = gamma[:1, :]
        return A, C


# Rows of base signals computed at a time by the Gram route (a block of ~12 MB at the
# default settings' 181 base columns).
GRAM_CHUNK_ROWS = 8192


class StackedColumns:
    """The columns of several (N, k) arrays side by side, each divided by its scale, formed
    only for the rows asked for: ``S[a:b]`` is again lazy, ``np.asarray(S[a:b])`` the
    (b - a) x n block. The subspace step's inputs ([U_r, Psi_i] at unit RMS) are thereby
    never copied whole.

    >>> a, b = np.arange(6.0).reshape(3, 2), np.ones((3, 1))
    >>> S = StackedColumns([a, b], np.array([1.0, 2.0, 0.5]))
    >>> S.shape, np.asarray(S[1:3]).tolist()
    ((3, 3), [[2.0, 1.5, 2.0], [4.0, 2.5, 2.0]])
    """

    def __init__(self, parts, scale=None, rows=None):
        self.parts = [np.asarray(p, dtype=float).reshape(len(p), -1) for p in parts]
        n_cols = sum(p.shape[1] for p in self.parts)
        self.scale = np.ones(n_cols) if scale is None else np.asarray(scale, dtype=float)
        self.rows = slice(0, len(self.parts[0])) if rows is None else rows
        self.shape = (len(range(len(self.parts[0]))[self.rows]), n_cols)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, idx):
        if not isinstance(idx, slice) or idx.step not in (None, 1):
            raise TypeError("StackedColumns takes contiguous row slices only")
        r = range(len(self.parts[0]))[self.rows][idx]
        return StackedColumns(self.parts, self.scale, slice(r.start, r.stop))

    def __array__(self, dtype=None, copy=None):
        out = np.empty(self.shape, order="F")
        col = 0
        for p in self.parts:
            out[:, col : col + p.shape[1]] = p[self.rows]
            col += p.shape[1]
        out /= self.scale
        return out if dtype is None else out.astype(dtype, copy=False)


def hankel_rows(u_future, u_past, y, start: int, stop: int, s: int):
    """Rows ``start..stop-1`` of the transposed block Hankel matrix [U_f; U_p; Y_p; Y_f]^T
    (column-major, as LAPACK takes it)."""
    blocks = [np.asarray(u_future[start + t : stop + t]) for t in range(s, 2 * s)]
    blocks += [np.asarray(u_past[start + t : stop + t]) for t in range(s)]
    blocks += [y[start + t : stop + t, None] for t in range(2 * s)]
    out = np.empty((stop - start, sum(blk.shape[1] for blk in blocks)), order="F")
    col = 0
    for blk in blocks:
        out[:, col : col + blk.shape[1]] = blk
        col += blk.shape[1]
    return out


def streamed_r(u_future, u_past, y, s: int, chunk: int | None = None, segments=None):
    """Triangular factor R of the QR of the transposed block Hankel matrix, streamed:
    chunks of its rows are built and folded into R one at a time. With ``segments``
    (:class:`lpvpc.io.segments.Segments`) each trial contributes the rows that lie inside it:
    no row spans a seam."""
    n_cols = s * (u_future.shape[1] + u_past.shape[1] + 2)
    chunk = chunk or max(4 * n_cols, CHUNK_ROWS)
    R, pending = None, []
    for a, b in (segments if segments is not None else [(0, len(y))]):
        n_rows = (b - a) - 2 * s + 1
        for start in range(0, max(n_rows, 0), chunk):
            rows = hankel_rows(u_future[a:b], u_past[a:b], y[a:b], start, min(start + chunk, n_rows), s)
            if R is None:  # the first fold needs at least as many rows as columns
                pending.append(rows)
                if sum(len(r) for r in pending) < n_cols:
                    continue
                rows, pending = np.vstack(pending), []
            R = fold_rows(R, rows)
    return R


def hankel_gram(X, blocks, segments=None, chunk: int = GRAM_CHUNK_ROWS):
    """Gram matrix H^T H of a transposed block Hankel matrix H, from lagged cross-products.

    X: (N, n_b) base signals, or a function ``rows(a, b)`` returning rows a..b-1 of them
    with attributes ``n`` (N) and ``n_cols`` (n_b), so that only ``chunk`` rows exist at a
    time; blocks: ``[(columns of X, shift), ...]`` in H's column
    order; H's row t, column (a, i) is X[t + i, a] for t = 0..N - S, S = 1 + the largest
    shift. With ``segments`` (:class:`lpvpc.io.segments.Segments`) each trial adds its own
    rows (none spans a seam): the Gram matrix is the sum of the trials'.

    Entry ((a, i), (b, j)), j >= i, is sum_u X[u, a] X[u + j - i, b] over the N - S + 1
    rows u = i.. of that window: a full lag product (one matrix product per lag and pair
    of column sets, summed over blocks of rows) minus the few rows at both ends.

    It equals H^T H of the rows :func:`hankel_rows` builds:

    >>> rng = np.random.default_rng(0)
    >>> u, y = rng.standard_normal((200, 3)), rng.standard_normal(200)
    >>> H = hankel_rows(u, u[:, :1], y, 0, 200 - 2 * 2 + 1, 2)  # horizon s = 2
    >>> blocks = [([0, 1, 2], 2), ([0, 1, 2], 3), ([0], 0), ([0], 1)] + [([3], i) for i in range(4)]
    >>> bool(np.allclose(hankel_gram(np.column_stack([u, y]), blocks, chunk=30), H.T @ H))
    True
    """
    if callable(X):
        rows, n_total, n_b = X, int(X.n), int(X.n_cols)
    else:
        X = np.asarray(X, dtype=float)
        rows, (n_total, n_b) = (lambda a, b: X[a:b]), X.shape
    blocks = [(_as_slice(c), int(i)) for c, i in blocks]
    S = 1 + max(i for _, i in blocks)
    sizes = [len(range(n_b)[c]) for c, _ in blocks]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    G = np.zeros((starts[-1], starts[-1]))
    # Blocks that share a column set share the lag products: key = (set of a, set of b, lag).
    keys = {}
    for p, (ca, i) in enumerate(blocks):
        for q, (cb, j) in enumerate(blocks):
            if j >= i and (j > i or q >= p):
                keys.setdefault((_key(ca), _key(cb), j - i), []).append((p, q))
    d_max = max(d for _, _, d in keys)
    chunk = max(int(chunk), 1)
    for a0, b0 in (segments if segments is not None else [(0, n_total)]):
        n = b0 - a0
        n_rows = n - S + 1
        if n_rows <= 0:
            continue
        head, tail = rows(a0, a0 + min(2 * S, n)), rows(a0 + max(n - 2 * S, 0), b0)
        t_off = n - len(tail)
        F = {}  # sum over all u of x_a[u] x_b[u + d], block of rows by block
        for c0 in range(0, n, chunk):
            c1 = min(c0 + chunk, n)
            x = rows(a0 + c0, a0 + min(c1 + d_max, n))
            for key, pqs in keys.items():
                d = key[2]
                m = min(c1, n - d) - c0
                if m > 0:
                    ca, cb = blocks[pqs[0][0]][0], blocks[pqs[0][1]][0]
                    prod = x[:m, ca].T @ x[d : d + m, cb]
                    F[key] = F[key] + prod if key in F else prod
        for (ka, kb, d), pqs in keys.items():
            ca, cb = blocks[pqs[0][0]][0], blocks[pqs[0][1]][0]
            Fk = F.get((ka, kb, d), 0.0)
            for p, q in pqs:
                i = blocks[p][1]
                u0 = i + n_rows - t_off  # the window is u = i .. i + n_rows - 1
                blk = Fk - head[:i, ca].T @ head[d : d + i, cb] - tail[u0 : len(tail) - d, ca].T @ tail[u0 + d :, cb]
                G[starts[p] : starts[p + 1], starts[q] : starts[q + 1]] += blk
                if q != p:
                    G[starts[q] : starts[q + 1], starts[p] : starts[p + 1]] += blk.T
    return G


def _as_slice(cols):
    """A contiguous run of column indices as a slice (its columns are then views, not copies)."""
    c = np.asarray(list(cols) if isinstance(cols, range) else cols, dtype=int).ravel()
    if c.size and np.all(np.diff(c) == 1):
        return slice(int(c[0]), int(c[-1]) + 1)
    return c


def _key(c):
    return (c.start, c.stop) if isinstance(c, slice) else c.tobytes()


# The Gram route's fixed cost (a few hundred small products in Python, ~10 ms) pays only
# above this many multiply-adds of the QR (rows x columns^2; 12,000 x 516^2 = 3e9 for a
# 2-minute record at default settings): smaller matrices take the QR.
GRAM_MIN_WORK = 1e8

# A base signal whose one-sample-earlier copy in another (or the same) column is this
# close (relative squared distance) is replaced, at every shift but the first, by its
# difference from that copy (see ``moesp_factor``).
PARTNER_TOL = 1e-2


def moesp_factor(u_future, u_past, y, s: int, segments=None, chunk: int | None = None):
    """(R, how) with R^T R = H^T H for the transposed block Hankel matrix H of
    :func:`hankel_rows`: the Cholesky factor of its Gram matrix (``how`` "gram"), zero rows
    for dependent columns, or the QR factor streamed from H's rows (``how`` "qr") when that
    Cholesky factor does not reproduce the Gram matrix (:func:`lpvpc.linalg.gram_factor_ok`:
    the Gram matrix squares the conditioning, and roundoff grown through a near-dependent
    column shows as a negative pivot or a residual).

    Conditioning: an LPV regressor column at one shift is nearly its neighbour's at the
    previous shift (a basis function of a slowly varying rho; a lagged position times it
    is the next lag's one sample later). Within the future-input and past-input blocks,
    such a column (a, i) is replaced by (a, i) - (b, i - 1), itself a block Hankel column
    of the base signal x_a(u) - x_b(u - 1): H T with T unit upper triangular has the same
    Q and the factor R T, well conditioned, from which R follows by column additions.

    >>> rng = np.random.default_rng(0)
    >>> u, y = rng.standard_normal((30000, 8)), rng.standard_normal(30000)
    >>> u[:, 1] = np.cumsum(u[:, 1]) / 100  # slowly varying: differenced at later shifts
    >>> R, how = moesp_factor(u, u[:, :1], y, 6)
    >>> H = hankel_rows(u, u[:, :1], y, 0, 30000 - 11, 6)
    >>> how, bool(np.allclose(R.T @ R, H.T @ H))
    ('gram', True)
    >>> moesp_factor(u[:3000, :2], u[:3000, :1], y[:3000], 3)[1]  # small: the QR costs less
    'qr'
    """
    n_f, n_p = u_future.shape[1], u_past.shape[1]
    bounds = segments if segments is not None else [(0, len(y))]
    n_rows = sum(max(b - a - 2 * s + 1, 0) for a, b in bounds)
    if n_rows * (s * (n_f + n_p + 2)) ** 2 < GRAM_MIN_WORK:
        return streamed_r(u_future, u_past, y, s, chunk, segments), "qr"
    groups = []  # future inputs at shifts s..2s-1, past inputs at 0..s-1
    for U, shifts in ((u_future, range(s, 2 * s)), (u_past, range(s))):
        # partners: ||x_a(u) - x_b(u - 1)||^2 from the lag-1 products (per trial: no seams),
        # a block of rows at a time
        sq, F1 = np.zeros(U.shape[1]), np.zeros((U.shape[1], U.shape[1]))
        for a0, b0 in bounds:
            for c0 in range(a0, b0 - 1, GRAM_CHUNK_ROWS):
                x = np.asarray(U[c0 : min(c0 + GRAM_CHUNK_ROWS + 1, b0)])
                sq += np.einsum("ij,ij->j", x[1:], x[1:])
                F1 += x[:-1].T @ x[1:]  # F1[b, a] = sum_u x_b(u - 1) x_a(u)
        dist = sq[None, :] + sq[:, None] - 2.0 * F1  # edges aside
        partner = np.argmin(dist, axis=0)
        ok = (sq > 0) & (dist[partner, np.arange(len(sq))] <= PARTNER_TOL * sq)
        groups.append((U, np.where(ok, partner, -1), shifts))
    n_b = 2 * sum(U.shape[1] for U, _, _ in groups) + 1

    def rows(a, b):
        """Rows a..b-1 of the base signals [U_f, M_f, U_p, M_p, y], M the differenced
        copies (row 0 of the record undifferenced, as at every record start before)."""
        out = np.empty((b - a, n_b), order="F")
        col, lo = 0, max(a - 1, 0)
        for U, partner, _ in groups:
            x = np.asarray(U[lo:b])
            n_u = x.shape[1]
            cur = x[a - lo :]
            out[:, col : col + n_u] = cur
            out[:, col + n_u : col + 2 * n_u] = cur
            k = np.flatnonzero(partner >= 0)
            if k.size:  # (the record's first row has no earlier one: kept as it is)
                out[int(a == 0):, col + n_u + k] = x[1:, k] - x[:-1, partner[k]]
            col += 2 * n_u
        out[:, -1] = y[a:b]
        return out

    rows.n, rows.n_cols = len(y), n_b
    blocks, back, col0 = [], [], 0  # back: for each H column, the column added back (or -1)
    for U, partner, shifts in groups:
        n_u = U.shape[1]
        for i in shifts:
            first = i == shifts[0]
            blocks.append((range(col0, col0 + n_u) if first else range(col0 + n_u, col0 + 2 * n_u), i))
            start = len(back)
            back += [-1] * n_u if first else [start - n_u + b if b >= 0 else -1 for b in partner]
        col0 += 2 * n_u
    G = hankel_gram(rows, blocks + [([n_b - 1], i) for i in range(2 * s)], segments)
    back += [-1] * (2 * s)
    if np.all(np.isfinite(G)):
        Rt, pivots = deflated_cholesky(G, DEFLATE_TOL)
        if gram_factor_ok(G, Rt, pivots):
            for j, k in enumerate(back):  # R = R_T T^-1: column (a, i) += column (b, i - 1), in order
                if k >= 0:
                    Rt[:, j] += Rt[:, k]
            return Rt, "gram"
    return streamed_r(u_future, u_past, y, s, chunk, segments), "qr"


def po_moesp(u_state, u_feedthrough, y, horizon: int, chunk: int | None = None, segments=None) -> SubspaceResult:
    """PO-MOESP for one output.

    u_state: (N, n_r) inputs that drive the state; u_feedthrough: (N, n_f) inputs that act
    only through the feedthrough; y: (N,) output; horizon: number of block rows s;
    segments: trials joined end to end (:class:`lpvpc.io.segments.Segments`; None: one record).

    >>> rng = np.random.default_rng(0)
    >>> u = rng.standard_normal(2000)
    >>> y = scipy.signal.lfilter([0.0, 1.0], np.poly([0.9, 0.7]), u)
    >>> res = po_moesp(u[:, None], np.zeros((2000, 0)), y, horizon=6)
    >>> int(np.sum(res.singular_values > 1e-8 * res.singular_values[0]))  # the state order
    2
    """
    y = np.asarray(y, dtype=float)
    s = int(horizon)
    u_state = np.asarray(u_state, dtype=float).reshape(len(y), -1)
    u_feedthrough = np.asarray(u_feedthrough, dtype=float).reshape(len(y), -1)
    n_inputs = u_state.shape[1] + u_feedthrough.shape[1]
    n_cols = s * (n_inputs + u_state.shape[1] + 2)
    lengths = [b - a for a, b in segments] if segments is not None else [len(y)]
    if sum(max(n - 2 * s + 1, 0) for n in lengths) < n_cols:
        raise InsufficientExcitationError(
            f"too few samples for subspace identification: {len(y)} samples"
            + (f" in {len(lengths)} trials" if len(lengths) > 1 else "")
            + f", need at least {n_cols + 2 * s - 1} for horizon {s} with {n_inputs} inputs"
        )
    # Scale every column to unit RMS: the QR is then well balanced between positions
    # (~0.02 rad), basis values (~1) and torques (~N m). Scaled block by block, never whole.
    scale_p = _rms(u_state)
    scale_f = np.concatenate([scale_p, _rms(u_feedthrough)])
    scale_y = _rms(y[:, None])[0]
    u_future = StackedColumns([u_state, u_feedthrough], scale_f)
    R, how = moesp_factor(u_future, StackedColumns([u_state], scale_p), y / scale_y, s, segments, chunk)
    L = R.T
    n_f = s * u_future.shape[1]
    n_w = s * (u_state.shape[1] + 1)
    L32 = L[n_f + n_w :, n_f : n_f + n_w]
    U, sv, _ = np.linalg.svd(L32)
    if not np.all(np.isfinite(sv)):
        raise IdentificationError("subspace step produced non-finite singular values")
    return SubspaceResult(singular_values=sv, left_vectors=U, horizon=s, factorisation=how)


def _rms(a):
    r = np.sqrt(np.einsum("ij,ij->j", a, a) / max(len(a), 1))  # (no N x n temporary)
    return np.where(r > 0, r, 1.0)


def candidate_orders(singular_values, max_order: int = 4, n_gaps: int = 2):
    """State orders at the ``n_gaps`` largest gaps of log singular values (up to max_order).

    The single largest gap often picks order 1 for a well-damped pole pair, so the orders
    at the two largest gaps are returned and the caller decides between them on fit.

    >>> candidate_orders(np.array([10.0, 1.0, 0.01, 0.009, 0.008, 0.007]))  # the gaps after 1 and 2
    [1, 2]
    """
    sv = np.asarray(singular_values, dtype=float)
    k = min(max_order, len(sv) - 1)
    gaps = np.log(sv[:k] + 1e-300) - np.log(sv[1 : k + 1] + 1e-300)
    orders = [int(i) + 1 for i in np.argsort(gaps)[::-1][:n_gaps]]
    return sorted(set(orders))


class PoleRefinement:
    """Refinement of the poles of (A, C) by variable projection on the complete fit.

    The column space of the reflex regressor (25) depends on A only through its
    characteristic polynomial ``1 + a_1 q^-1 + ... + a_m q^-m``, so the residual of the
    unconstrained least-squares fit of y on [Psi_i, U_r, X(a)], X(a) = [q^-1 W, ...,
    q^-m W] with W = U_r / a(q), is a function of the m coefficients alone. Its minimum,
    started from the MOESP poles, corrects the bias that MOESP's many instruments leave in
    the poles at the price of a few dozen cheap projections.

    range([Psi_i, U_r]) does not depend on the poles: it is factored once here and shared
    by every state order and evaluation. The Jacobian is the exact variable-projection
    one (Golub and Pereyra 1973), from m + 1 filtered vectors; finite differences would
    cost m extra residuals per step.

    Started from wrong poles (0.8, 0.5), the refinement finds the system's (0.9, 0.7) in noise:

    >>> rng = np.random.default_rng(0)
    >>> u = rng.standard_normal(2000)
    >>> y = scipy.signal.lfilter([0.0, 1.0], np.poly([0.9, 0.7]), u) + 0.1 * rng.standard_normal(2000)
    >>> A0, _ = companion_form(np.poly([0.8, 0.5])[1:])
    >>> A, C, result = PoleRefinement(u[:, None], np.zeros((2000, 0)), y).refine(A0)
    >>> np.sort(np.linalg.eigvals(A).real).round(2)
    array([0.7, 0.9])
    """

    def __init__(self, u_state, fixed_regressor, y, segments=None, max_radius=STABLE_POLE_RADIUS):
        self.u = np.asfortranarray(u_state)  # lfilter runs along columns
        self.max_radius = float(min(max_radius, STABLE_POLE_RADIUS))  # poles stay inside this radius
        # Trials joined end to end: filters and delays restart in each (lpvpc.io.segments).
        self.segments = segments if segments is not None else Segments((), len(y))
        self.Q0 = orthonormal_range(np.hstack([fixed_regressor, u_state]))
        self.y_perp = y - self.Q0 @ (self.Q0.T @ y)
        self._cache = (None, None)

    def refine(self, A0, max_nfev: int = 60):
        """(A, C) in observable canonical form, and the optimiser result. MOESP poles at
        or beyond ``max_radius``, where the optimiser refuses to evaluate, start just inside
        it; the others where MOESP put them."""
        z = np.linalg.eigvals(A0)
        r = np.abs(z)
        inside = 0.999 * self.max_radius
        den0 = np.poly(np.where(r >= self.max_radius, z / np.maximum(r, 1e-300) * inside, z)).real[1:]
        result = scipy.optimize.least_squares(self._residual, den0, jac=self._jacobian, method="lm",
                                              max_nfev=max_nfev, x_scale="jac", ftol=1e-6, xtol=1e-6)
        A, C = companion_form(result.x)
        return A, C, result

    def _fit(self, den):
        """Least-squares fit at ``den`` (cached: the optimiser asks for the residual and
        the Jacobian at the same point), or None where a pole reaches ``max_radius``
        (unstable, or slower than the allowed time constant).

        X is never projected explicitly: with B = Q0^T X the projected Gram matrix is
        X^T X - B^T B and the projection of any X w is X w - Q0 (B w). These normal
        equations on scaled columns are several times cheaper than a QR per evaluation,
        and the residual only steers the optimiser (the final fit is redone by QR).
        """
        key = den.tobytes()
        if self._cache[0] == key:
            return self._cache[1]
        fit = None
        if np.all(np.abs(np.roots(np.r_[1.0, den])) < self.max_radius):
            a = np.r_[1.0, den]
            W = self.segments.map(lambda x: scipy.signal.lfilter([1.0], a, x, axis=0), self.u)
            X = self.segments.map(_delays, W, m=len(den))
            B = self.Q0.T @ X
            G = X.T @ X - B.T @ B
            scale = np.sqrt(np.maximum(np.diag(G), 0.0))
            scale[scale == 0] = 1.0
            # pseudo-inverse (of the scaled Gram matrix): X may be rank-deficient
            G_pinv = np.linalg.pinv(G / np.outer(scale, scale), hermitian=True) / np.outer(scale, scale)
            coef = G_pinv @ (X.T @ self.y_perp)
            fit = {"W": W, "X": X, "B": B, "G_pinv": G_pinv, "coef": coef, "r": self.y_perp - self._perp_x(X, B, coef)}
        self._cache = (key, fit)
        return fit

    def _perp_x(self, X, B, w):
        """(X - Q0 Q0^T X) w."""
        return X @ w - self.Q0 @ (B @ w)

    def _residual(self, den):
        fit = self._fit(den)
        return 10.0 * self.y_perp if fit is None else fit["r"]

    def _jacobian(self, den):
        """d r / d a_k = -P dX_k c - X^+T dX_k^T r with P the projector off [Psi_i, U_r, X],
        c the coefficients of X and dX_k = -[q^-(k+1) V, ..., q^-(k+m) V], V = W / a(q).

        V itself is not needed: V c_j = (W c_j) / a(q), and V^T v = W^T F^T v where the
        transposed filter F^T runs backwards in time.
        """
        fit = self._fit(den)
        m = len(den)
        if fit is None:
            return np.zeros((len(self.y_perp), m))
        W, X, B, r, G_pinv = fit["W"], fit["X"], fit["B"], fit["r"], fit["G_pinv"]
        a = np.r_[1.0, den]
        seg = self.segments
        Vc = seg.map(lambda x: scipy.signal.lfilter([1.0], a, x, axis=0), W @ fit["coef"].reshape(m, -1).T)
        z = sum(seg.map(_delay, Vc[:, j - 1], lag=j) for j in range(1, m + 1))  # -dX_k c = q^-k z
        S = np.column_stack([seg.map(_delay, z, lag=k) for k in range(1, m + 1)])
        g = seg.map(lambda x: scipy.signal.lfilter([1.0], a, x[::-1])[::-1], r)  # F^T r
        # (q^-lag V)^T r = W^T (g advanced by lag) within each trial, all lags in one product
        lags = range(2, 2 * m + 1)
        g_lags = np.zeros((len(g), len(lags)))
        for i, j in seg:
            for c, lag in enumerate(lags):
                g_lags[i : j - lag, c] = g[i + lag : j]
        corr = dict(zip(lags, (W.T @ g_lags).T))
        H = np.column_stack([np.concatenate([corr[j + k] for j in range(1, m + 1)]) for k in range(1, m + 1)])
        # P S + P X w with P the projector off range(Q0), in two passes over Q0: with
        # T = Q0^T S, X^T P S = X^T S - B^T T and P S + P X w = S + X w - Q0 (T + B w)
        T = self.Q0.T @ S
        w = G_pinv @ (H - (X.T @ S - B.T @ T))
        return S + X @ w - self.Q0 @ (T + B @ w)


def _delays(W, m: int):
    """[q^-1 W, ..., q^-m W] (zeros before the start)."""
    n, k = W.shape
    X = np.zeros((n, m * k))
    for j in range(1, m + 1):
        X[j:, (j - 1) * k : j * k] = W[:-j]
    return X


def _delay(a, lag: int):
    """a delayed by ``lag`` samples along axis 0, zeros before the start."""
    out = np.zeros_like(a)
    out[lag:] = a[:-lag]
    return out
