"""The cross-validation engine: least-squares fits from per-fold normal equations.

Both users of cross-validation keep, for every fold f, the Gram matrix ``G[f] = X_f^T X_f``
and the vector ``b[f] = X_f^T y_f`` of that fold's rows: the structure search
(:class:`lpvpc.identification.selection.StructureSearch`, folds at position levels) and the diagnosis
(:class:`lpvpc.diagnosis.cv.BlockCV`, blocked folds in time). A fit on every fold but f is
then a small solve of the summed systems without f, and the held-out squared error follows
from ``G[f]`` and ``b[f]`` without the rows. This module does that part for both, with the
ridge as a parameter:

- ``reference="diagonal"``: columns scaled to a unit diagonal of the training Gram matrix
  (Jacobi), then ``ridge`` times the identity added (the structure search: 1e-10);
- ``reference="largest_eigenvalue"``: an eigenvalue pseudo-inverse with ``ridge`` times
  the largest eigenvalue added to every eigenvalue (the diagnosis: 1e-8, its fixed design
  1e-4; rank-deficient combinations of blocks are handled, not refused).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

__all__ = ["REFERENCES", "solve_normal", "fold_fits", "held_out_sse"]

#: What ``ridge`` is relative to in :func:`solve_normal`.
REFERENCES = ("diagonal", "largest_eigenvalue")


def solve_normal(G, b, ridge: float, reference: str = "diagonal") -> np.ndarray:
    """Regularised least-squares coefficients from normal equations ``G theta = b``.

    Parameters
    ----------
    G : ndarray, shape (..., n, n)
        Symmetric positive semi-definite Gram matrices (a stack: one solve each).
    b : ndarray, shape (..., n) or (..., n, k)
        Right-hand sides (k of them per matrix in the second form).
    ridge : float
        Relative ridge, >= 0.
    reference : {"diagonal", "largest_eigenvalue"}
        ``"diagonal"``: ``(D^-1 G D^-1 + ridge I) D theta = D^-1 b`` with D the square root
        of G's diagonal (stacks of any shape). ``"largest_eigenvalue"``: eigenvalues ``w`` of
        G clipped at 0, ``theta = V diag(1 / (w + ridge max(w))) V^T b`` (one matrix at a
        time; near-null directions are damped rather than amplified).

    Returns
    -------
    ndarray
        theta, the shape of ``b``.

    Raises
    ------
    ValueError
        An unknown ``reference``.

    Examples
    --------
    >>> G = np.array([[4.0, 0.0], [0.0, 1.0]])
    >>> solve_normal(G, np.array([8.0, 3.0]), 0.0).tolist()
    [2.0, 3.0]
    >>> solve_normal(G, np.array([8.0, 3.0]), 0.0, "largest_eigenvalue").tolist()
    [2.0, 3.0]
    """
    G, b = np.asarray(G, dtype=float), np.asarray(b, dtype=float)
    if reference == "diagonal":
        column = b.ndim == G.ndim - 1  # (..., n): one right-hand side per matrix
        B = b[..., None] if column else b
        s = np.sqrt(np.maximum(np.einsum("...ii->...i", G), 1e-300))
        A = G / (s[..., :, None] * s[..., None, :]) + ridge * np.eye(G.shape[-1])
        theta = np.linalg.solve(A, B / s[..., :, None]) / s[..., :, None]
        return theta[..., 0] if column else theta
    if reference == "largest_eigenvalue":
        if G.ndim > 2:
            return np.stack([solve_normal(g, c, ridge, reference) for g, c in zip(G, b)])
        w, V = scipy.linalg.eigh(G, check_finite=False)
        w = np.maximum(w, 0.0)
        scale = w + ridge * max(w[-1], 1e-300)
        return V @ ((V.T @ b) / (scale if b.ndim == 1 else scale[:, None]))
    raise ValueError(f"reference must be one of {REFERENCES}, not {reference!r}")


def fold_fits(G, b, ridge: float, reference: str = "diagonal"):
    """Coefficients fitted on every fold but one, from the folds' normal equations.

    Parameters
    ----------
    G : numpy.ndarray
        Each fold's Gram matrix ``X_f^T X_f``, shape (K, n, n).
    b : numpy.ndarray
        Each fold's ``X_f^T y_f``, shape (K, n).
    ridge, reference
        As in :func:`solve_normal`.

    Returns
    -------
    theta : numpy.ndarray
        ``theta[f]``: fitted on every fold but f; shape (K, n).
    G_train, b_train : numpy.ndarray
        The training systems (the sums over the other folds) it solved.

    Examples
    --------
    Two folds of y = 2 x: each fold's fit, from the other, finds the slope:

    >>> x = np.arange(1.0, 7.0)
    >>> G = np.array([[[x[:3] @ x[:3]]], [[x[3:] @ x[3:]]]])
    >>> b = np.array([[x[:3] @ (2 * x[:3])], [x[3:] @ (2 * x[3:])]])
    >>> np.round(fold_fits(G, b, 1e-10)[0], 6).tolist()
    [[2.0], [2.0]]
    """
    G_train, b_train = G.sum(axis=0) - G, b.sum(axis=0) - b
    return solve_normal(G_train, b_train, ridge, reference), G_train, b_train


def held_out_sse(yy, theta, G, b) -> np.ndarray:
    """Squared error of coefficients on rows known only by their normal equations:
    ``y^T y - 2 theta^T b + theta^T G theta`` per fold.

    Parameters
    ----------
    yy : numpy.ndarray
        Each fold's ``y_f^T y_f``, shape (K,).
    theta : numpy.ndarray
        The coefficients scored on fold f (:func:`fold_fits`), shape (K, n).
    G, b : numpy.ndarray
        The scored rows' Gram matrices and ``X^T y``, shapes (K, n, n) and (K, n).

    Returns
    -------
    numpy.ndarray
        The squared error on each fold, shape (K,).

    Examples
    --------
    >>> held_out_sse(np.array([5.0]), np.array([[1.0]]), np.array([[[1.0]]]), np.array([[2.0]])).tolist()
    [2.0]
    """
    return yy - 2.0 * np.einsum("ki,ki->k", theta, b) + np.einsum("ki,kij,kj->k", theta, G, theta)
