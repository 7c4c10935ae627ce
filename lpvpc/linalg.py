"""Rank-revealing least-squares helpers shared by the identification steps."""

from __future__ import annotations

import functools
import os
from contextlib import contextmanager

import numpy as np
import scipy.linalg
import scipy.linalg.lapack
from threadpoolctl import threadpool_limits

from .errors import InsufficientExcitationError

RANK_TOL = 1e-9  # relative to the largest |R_ii| of a pivoted QR

#: Environment variables by which a user sets the BLAS thread count; one_blas_thread leaves
#: any such setting alone.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def one_blas_thread():
    """Run the enclosed linear algebra on one BLAS thread, unless the user has chosen a
    thread count (:data:`BLAS_THREAD_VARIABLES`).

    Identification is many tall-skinny QR and least-squares steps, which BLAS threads slow
    down: a 2-minute 100 Hz record took 1.05 s with OpenBLAS's default threads on 2 cores and
    0.47 s on one; a 15-minute record 4.8 s either way (benchmarks/results/identify_floor.txt).
    The command line and the demo set the variables before numpy loads; this covers a
    library user's ``import lpvpc`` in a notebook, where BLAS has already started its threads.

    >>> from threadpoolctl import threadpool_info
    >>> with one_blas_thread():
    ...     counts = {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}
    >>> counts <= {1} or any(v in os.environ for v in BLAS_THREAD_VARIABLES)
    True
    """
    if any(v in os.environ for v in BLAS_THREAD_VARIABLES):
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def on_one_blas_thread(func):
    """Decorate ``func`` to run inside :func:`one_blas_thread`.

    For the library's long entry points that are many small least-squares fits (the
    diagnosis's cross-validated candidates, the improve loop), which BLAS threads slow down
    as they slow identification (docs/design_notes.md, "One BLAS thread"). The command line
    already runs on one thread; this gives a Python session the same speed.

    >>> from threadpoolctl import threadpool_info
    >>> @on_one_blas_thread
    ... def blas_threads():
    ...     return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}
    >>> blas_threads() <= {1} or any(v in os.environ for v in BLAS_THREAD_VARIABLES)
    True
    >>> blas_threads.__name__
    'blas_threads'
    """
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return func(*args, **kwargs)
    return wrapper


def pivoted_qr(M):
    """Economic pivoted QR of M: (Q, R, piv, numerical rank).

    A regressor whose fourth column is the sum of the first two has rank 3:

    >>> M = np.random.default_rng(0).standard_normal((100, 3))
    >>> Q, R, piv, rank = pivoted_qr(np.column_stack([M, M[:, 0] + M[:, 1]]))
    >>> rank, bool(np.allclose(Q @ R, np.column_stack([M, M[:, 0] + M[:, 1]])[:, piv]))
    (3, True)
    """
    Q, R, piv = scipy.linalg.qr(M, mode="economic", pivoting=True, check_finite=False)
    diag = np.abs(np.diag(R))
    rank = int(np.sum(diag > RANK_TOL * diag[0])) if diag.size and diag[0] > 0 else 0
    return Q, R, piv, rank


def orthonormal_range(M):
    """Orthonormal basis of range(M).

    >>> M = np.random.default_rng(0).standard_normal((100, 3))
    >>> Q = orthonormal_range(np.column_stack([M, 2 * M[:, 0]]))
    >>> Q.shape, bool(np.allclose(Q.T @ Q, np.eye(3)))
    ((100, 3), True)
    """
    Q, _, _, rank = pivoted_qr(M)
    return Q[:, :rank]


CHUNK_ROWS = 2000  # rows folded in at a time (at 12,000 x 88, 2x faster than one geqrf)


def fold_rows(R, rows):
    """Triangular factor of [R; rows]; R None starts one (rows then at least as many as
    columns). LAPACK's triangular-pentagonal QR (tpqrt) skips the zeros below R's diagonal
    that a QR of the stacked matrix would work through.

    Rows folded in two chunks give the factor of the whole matrix (R^T R = M^T M):

    >>> M = np.random.default_rng(0).standard_normal((100, 3))
    >>> R = fold_rows(fold_rows(None, M[:50]), M[50:])
    >>> bool(np.allclose(R.T @ R, M.T @ M))
    True
    """
    rows = np.asfortranarray(rows, dtype=float)
    n = rows.shape[1]
    if R is None:
        lwork = int(scipy.linalg.lapack.dgeqrf(rows, lwork=-1)[2][0])  # the default one is too small to block
        qr, _, _, info = scipy.linalg.lapack.dgeqrf(rows, lwork=lwork, overwrite_a=True)
        R = np.asfortranarray(np.triu(qr[:n]))
    else:
        R, _, _, info = scipy.linalg.lapack.dtpqrt(0, min(32, n), R, rows, overwrite_a=True, overwrite_b=True)
    if info != 0:
        raise np.linalg.LinAlgError(f"QR failed (LAPACK info {info})")
    return R


def triangular_factor(M):
    """R (n x n) of the QR of a tall M (N x n), without forming Q.

    Least-squares problems in the columns of M have the same solutions and residual norms
    on R as on M (M = Q R with orthonormal Q), at n rows instead of N.

    >>> M = np.random.default_rng(0).standard_normal((1000, 3))
    >>> y = M @ np.array([1.0, -2.0, 0.5])
    >>> R = triangular_factor(np.column_stack([M, y]))  # least squares on 4 rows instead of 1000
    >>> np.linalg.solve(R[:3, :3], R[:3, 3]).round(12)
    array([ 1. , -2. ,  0.5])

    M may be a list of arrays (N rows each; 1-D ones are columns): the factor of their
    columns side by side, stacked a block of rows at a time instead of copied whole (a
    30-minute record's final regressor is 144 MB):

    >>> bool(np.allclose(np.abs(triangular_factor([M, y])), np.abs(R)))
    True
    """
    if isinstance(M, (list, tuple)):
        parts = [np.asarray(m, dtype=float).reshape(len(m), -1) for m in M]
        n, n_cols = len(parts[0]), sum(m.shape[1] for m in parts)

        def block(a, b):
            b = min(b, n)
            out = np.empty((b - a, n_cols), order="F")
            col = 0
            for m in parts:
                out[:, col : col + m.shape[1]] = m[a:b]
                col += m.shape[1]
            return out
    else:
        n, n_cols = M.shape
        block = lambda a, b: M[a:b]  # noqa: E731
    chunk = max(CHUNK_ROWS, n_cols)
    R = None
    for start in range(0, n, chunk):
        R = fold_rows(R, block(start, start + chunk))
    return R


def tall_lstsq(M, y):
    """Least-squares solution of M x ~ y for a tall M (N x n), computed on the triangular
    factor of [M, y] (same solution; no N x n copy, which numpy's lstsq makes).

    >>> M = np.random.default_rng(0).standard_normal((1000, 3))
    >>> tall_lstsq(M, M @ np.array([1.0, -2.0, 0.5])).round(12)
    array([ 1. , -2. ,  0.5])
    """
    R = triangular_factor([M, y])
    return np.linalg.lstsq(R[:, :-1], R[:, -1], rcond=None)[0]


# Pivots of a Gram matrix's Cholesky factor, relative to the column's own squared norm.
# At or below DEFLATE_TOL a pivot is roundoff (a column that repeats or combines earlier
# ones: the Gram matrices of the subspace step leave pivots of 1e-15..1e-14 there, the
# weakest independent columns 1e-13..1e-10): the column is dependent and gets a zero row.
# The Gram matrix squares the conditioning, so the factor is checked: R^T R off G by more
# than GRAM_RESIDUAL_TOL (relative to G's largest entry: roundoff grown through a
# near-dependent column, seen as pivots of -40) sends the caller to a QR.
DEFLATE_TOL = 1e-13
GRAM_RESIDUAL_TOL = 1e-10


def gram_factor_ok(G, R, pivots) -> bool:
    """True when R from :func:`deflated_cholesky` reproduces G: finite, and
    max |R^T R - G| <= GRAM_RESIDUAL_TOL max |G| (``pivots``, relative to each column's
    norm, may be below zero for columns of roundoff size: what counts is the residual).

    >>> G = np.array([[1.0, 1.0], [1.0, 1.0 + 1e-14]])  # the second column's pivot is 1e-14: deflated
    >>> gram_factor_ok(G, *deflated_cholesky(G))
    True
    >>> G = np.array([[1.0, 1.0], [1.0, 0.5]])  # not positive semi-definite
    >>> gram_factor_ok(G, *deflated_cholesky(G))
    False
    """
    if not np.all(np.isfinite(R)):
        return False
    scale = np.abs(G).max(initial=0.0)
    return bool(np.abs(R.T @ R - G).max(initial=0.0) <= GRAM_RESIDUAL_TOL * scale)


def deflated_cholesky(G, tol: float = DEFLATE_TOL, block: int = 64):
    """Upper triangular R with R^T R = G for a symmetric positive semi-definite G, without
    pivoting (column order kept, as an LQ/QR factor of the data matrix would be); a column
    whose pivot is at most ``tol`` times its diagonal entry is dependent on the earlier
    ones and gets a zero row. Returns (R, pivots relative to diag(G)); pivots <= tol mark
    the dependent columns. Blocked: the panel updates are matrix products.

    The Gram matrix of a data matrix whose third column repeats the first gives the QR
    factor of the data matrix (up to row signs), with a zero row for the repeat:

    >>> M = np.random.default_rng(0).standard_normal((100, 3))
    >>> M = np.column_stack([M[:, 0], M[:, 1], M[:, 0], M[:, 2]])
    >>> R, pivots = deflated_cholesky(M.T @ M)
    >>> bool(pivots[2] <= DEFLATE_TOL), bool(np.all(R[2] == 0))
    (True, True)
    >>> R_qr = np.linalg.qr(M[:, [0, 1, 3]], mode="r")
    >>> bool(np.allclose(np.abs(R[[0, 1, 3]]), np.abs(R_qr[:, [0, 1, 0, 2]])))
    True
    """
    A = np.array(G, dtype=float)
    n = len(A)
    diag0 = np.diag(A).copy()
    diag0[~(diag0 > 0)] = 1.0
    R = np.zeros_like(A)
    kept = np.zeros(n, dtype=bool)
    pivots = np.zeros(n)
    for k0 in range(0, n, block):
        k1 = min(k0 + block, n)
        A11 = A[k0:k1, k0:k1]
        R11 = R[k0:k1, k0:k1]
        for j in range(k1 - k0):  # unblocked inside the diagonal block
            piv = A11[j, j] - R11[:j, j] @ R11[:j, j]
            pivots[k0 + j] = piv / diag0[k0 + j]
            if not pivots[k0 + j] > tol:
                continue
            kept[k0 + j] = True
            r = np.sqrt(piv)
            R11[j, j] = r
            R11[j, j + 1 :] = (A11[j, j + 1 :] - R11[:j, j] @ R11[:j, j + 1 :]) / r
        if k1 < n:
            kk = kept[k0:k1]
            R12 = np.zeros((k1 - k0, n - k1))
            R12[kk] = scipy.linalg.solve_triangular(R11[np.ix_(kk, kk)], A[k0:k1, k1:][kk], trans="T",
                                                    check_finite=False)
            R[k0:k1, k1:] = R12
            A[k1:, k1:] -= R12.T @ R12
    return R, pivots


def project_out_and_solve(Psi_r, Psi_i, y):
    """theta_i of eqs. (27)-(28) by least squares after projecting out range(Psi_r).

    Equivalent to C^+ Psi_i^+ (I - Psi_r Psi_r^+) Y when Psi_i has full column rank
    (Frisch-Waugh-Lovell) but costs O(N n^2) instead of O(N^2).
    """
    Q_r = orthonormal_range(Psi_r)
    Pi_perp = Psi_i - Q_r @ (Q_r.T @ Psi_i)
    y_perp = y - Q_r @ (Q_r.T @ y)
    Q, R, piv = check_full_rank(Pi_perp, "intrinsic", "after removing the reflex part ")
    theta = np.empty(Psi_i.shape[1])
    theta[piv] = scipy.linalg.solve_triangular(R, Q.T @ y_perp, check_finite=False)
    return theta


def check_full_rank(M, name, context=""):
    """Pivoted QR (Q, R, piv) of M; raises InsufficientExcitationError naming the
    dependent columns if M is rank-deficient.

    >>> M = np.column_stack([np.arange(5.0), 2 * np.arange(5.0)])
    >>> check_full_rank(M, "intrinsic")
    Traceback (most recent call last):
    ...
    lpvpc.errors.InsufficientExcitationError: rank-deficient intrinsic regressor: rank 1 of 2 columns (columns [...] are dependent); ...
    """
    Q, R, piv, rank = pivoted_qr(M)
    if rank < M.shape[1]:
        raise InsufficientExcitationError(
            f"rank-deficient {name} regressor: rank {rank} of {M.shape[1]} columns {context}(columns "
            f"{sorted(piv[rank:].tolist())[:10]} are dependent); reduce the basis order, keep IRF lags "
            f"below the reflex delay, or check that the scheduling variable varies"
        )
    return Q, R, piv
