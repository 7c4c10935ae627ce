"""Rank-revealing least-squares helpers shared by the identification steps."""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

RANK_TOL = 1e-9  # relative to the largest |R_ii| of a pivoted QR


def pivoted_qr(M):
    """Economic pivoted QR of M: (Q, R, piv, numerical rank)."""
    Q, R, piv = scipy.linalg.qr(M, mode="economic", pivoting=True, check_finite=False)
    diag = np.abs(np.diag(R))
    rank = int(np.sum(diag > RANK_TOL * diag[0])) if diag.size and diag[0] > 0 else 0
    return Q, R, piv, rank


def orthonormal_range(M):
    """Orthonormal basis of range(M)."""
    Q, _, _, rank = pivoted_qr(M)
    return Q[:, :rank]


def triangular_factor(M):
    """R (n x n) of the QR of a tall M (N x n), without forming Q.

    Least-squares problems in the columns of M have the same solutions and residual norms
    on R as on M (M = Q R with orthonormal Q), at n rows instead of N.
    """
    qr, _, _, info = scipy.linalg.lapack.dgeqrf(np.asfortranarray(M, dtype=float), overwrite_a=True)
    if info != 0:
        raise np.linalg.LinAlgError(f"LAPACK dgeqrf info {info}")
    return np.triu(qr[: M.shape[1]])
