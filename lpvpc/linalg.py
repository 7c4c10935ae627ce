"""Rank-revealing least-squares helpers shared by the identification steps."""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

RANK_TOL = 1e-9  # relative to the largest |R_ii| of a pivoted QR


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
    """
    chunk = max(CHUNK_ROWS, M.shape[1])
    R = None
    for start in range(0, len(M), chunk):
        R = fold_rows(R, M[start : start + chunk])
    return R
