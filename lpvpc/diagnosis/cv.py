"""Blocked cross-validation and the paired test: how the diagnosis scores a fit on data it
was not fitted to.

:class:`BlockCV` fits any combination of named column blocks on K - 1 contiguous (or
interleaved) folds and predicts the held-out one; :func:`paired_test` says whether one
held-out residual is smaller than another (batch means over 2-s blocks: the residual is
coloured). The fold fits and scores are :mod:`lpvpc.identification.crossval`'s, the engine the structure search uses
too (here with the ridge relative to the largest eigenvalue). Both are independent of the model: the surrogate (:mod:`lpvpc.diagnosis.surrogate`)
fills them with the model's structure.
"""

from __future__ import annotations

import numpy as np
import scipy.stats

from ..identification.crossval import fold_fits, solve_normal

FOLDS = 10
BLOCK_S = 2.0  # s: blocks of the variance estimate of the paired test


class BlockCV:
    """Blocked K-fold cross-validation of least-squares fits built from named column blocks.

    Gram products of every pair of blocks are computed once per fold, so fitting any
    combination of blocks on K - 1 folds costs only a small solve per fold. Columns are
    scaled to unit RMS; solves use an eigenvalue pseudo-inverse (rank-deficient
    combinations are handled, not refused).
    """

    def __init__(self, y, folds=FOLDS, mask=None, interleave=None):
        """``mask``: boolean (N,), samples left out of every fit and score (rows zeroed).
        ``interleave``: None (K contiguous folds) or a block length in samples: blocks of
        that length are dealt to the folds in turn, so every fold holds parts of the whole
        record (on a short record each position level is then seen by the other folds too)."""
        self.w = None if mask is None else np.asarray(mask, dtype=float)
        self.y = np.asarray(y, dtype=float) * (1.0 if self.w is None else self.w)
        n = len(self.y)
        self.edges = np.linspace(0, n, folds + 1).astype(int)
        if interleave:
            fold_of = (np.arange(n) // int(interleave)) % folds
            self.parts = [np.flatnonzero(fold_of == f) for f in range(folds)]
        else:
            self.parts = [slice(a, b) for a, b in zip(self.edges[:-1], self.edges[1:])]
        self.K = folds
        self.ridge = RIDGE
        self.blocks = {}
        self._cross = {}
        self._yb = {}
        self.yy = np.array([self.y[ix] @ self.y[ix] for ix in self.parts])


    def add(self, name, X):
        X = np.asarray(X, dtype=float)
        if X.ndim == 1:
            X = X[:, None]
        if self.w is not None:
            X = X * self.w[:, None]
        s = np.sqrt(np.mean(X**2, axis=0))
        s[s == 0] = 1.0
        self.blocks[name] = X / s
        return name

    def _pair(self, a, b):
        """Per-fold products A_f^T B_f, shape (K, p_a, p_b) (cached, either order)."""
        if (a, b) in self._cross:
            return self._cross[(a, b)]
        if (b, a) in self._cross:
            return np.transpose(self._cross[(b, a)], (0, 2, 1))
        A, B = self.blocks[a], self.blocks[b]
        self._cross[(a, b)] = np.stack([A[ix].T @ B[ix] for ix in self.parts])
        return self._cross[(a, b)]

    def _ycross(self, a):
        if a not in self._yb:
            A = self.blocks[a]
            self._yb[a] = np.stack([A[ix].T @ self.y[ix] for ix in self.parts])
        return self._yb[a]

    def fold_systems(self, names):
        """Per fold: (G_f, b_f) of the held-out fold for the blocks ``names``."""
        G = np.concatenate([np.concatenate([self._pair(a, b) for b in names], axis=2) for a in names], axis=1)
        b = np.concatenate([self._ycross(a) for a in names], axis=1)
        return G, b

    def fit(self, names):
        """Held-out residual (N,) and training RSS per fold for the blocks ``names``."""
        if not names:  # nothing fitted: the target itself
            return self.y.copy(), self.yy.sum() - self.yy
        theta, G_train, b_train = fold_fits(*self.fold_systems(names), self.ridge, "largest_eigenvalue")
        resid = np.empty_like(self.y)
        rss_train = self.yy.sum() - self.yy  # y^T y of the training rows, then minus the fit's share
        X = np.hstack([self.blocks[a] for a in names])
        for f, ix in enumerate(self.parts):
            beta, G, b = theta[f], G_train[f], b_train[f]
            resid[ix] = self.y[ix] - X[ix] @ beta
            rss_train[f] = rss_train[f] - 2 * beta @ b + beta @ G @ beta
        return resid, rss_train


RIDGE = 1e-8  # relative to the largest eigenvalue of the (column-scaled) Gram matrix
FIXED_RIDGE = 1e-4  # the fixed design's candidates model a small residual: shrink them toward the model


def _solve_psd(G, b, ridge=RIDGE):
    """Least-squares coefficients from normal equations with a tiny relative ridge
    (:func:`lpvpc.identification.crossval.solve_normal` relative to the largest eigenvalue).

    The reflex columns are nearly collinear (neighbouring basis functions of the
    nonlinearity through the same filter, the drive through filters that differ little);
    without the ridge, directions with eigenvalues ~1e-12 of the largest turn fold-to-fold
    noise into large held-out errors. The intrinsic block's smallest
    eigenvalues (~1e-5) are untouched."""
    return solve_normal(G, b, ridge, "largest_eigenvalue")


def paired_test(r0, r1, fs, block_s=BLOCK_S):
    """One-sided test that the squared held-out residual r1 is smaller than r0 on average.

    Returns (t, p). The variance of the mean of d = r0^2 - r1^2 comes from means over
    blocks of ``block_s`` seconds (batch means), which absorbs the residual's colour.
    """
    t, p, _ = _block_tests(r0, r1, fs, block_s, robust=False)
    return t, p


def robust_paired_test(r0, r1, fs, block_s=BLOCK_S):
    """:func:`paired_test` made robust to single blocks: returns (t, p, p_mean) where p is
    the smaller of the batch-means t test's p (``p_mean``) and the Wilcoxon signed-rank
    test's on the same block means, doubled (Bonferroni over the two tests, so the level
    holds).

    The t test alone loses its power to one or two blocks where a candidate predicts much
    worse or better than elsewhere (a slow signal extrapolated into a held-out fold;
    docs/design_notes.md, "Diagnosis significance"). The signed-rank test alone misses effects
    confined to a few blocks (reflex habituation, early in the trial); together they keep
    both. It says most blocks improve, not by how much: tiny systematic gains pass it too,
    so small gains are judged on ``p_mean`` (:func:`lpvpc.diagnosis.candidates.passes`).
    benchmarks/results/diagnose_significance.txt compares them on every design.

    >>> rng = np.random.default_rng(1)
    >>> r0 = rng.standard_normal(12000)
    >>> r1 = 0.97 * r0
    >>> r1[5000:5200] = 2.0 * r0[5000:5200]  # one 2-s block much worse
    >>> t, p, p_mean = robust_paired_test(r0, r1, 100.0)
    >>> bool(p_mean > 0.1 and p < 1e-6)
    True
    """
    return _block_tests(r0, r1, fs, block_s, robust=True)


def _block_tests(r0, r1, fs, block_s, robust):
    d = r0**2 - r1**2
    b = max(1, int(round(block_s * fs)))
    nb = len(d) // b
    if nb < 3:
        return 0.0, 1.0, 1.0
    means = d[: nb * b].reshape(nb, b).mean(axis=1)
    sd = means.std(ddof=1)
    if sd == 0:
        return (np.inf, 0.0, 0.0) if means.mean() > 0 else (0.0, 1.0, 1.0)
    t = float(means.mean() / (sd / np.sqrt(nb)))
    p_mean = float(scipy.stats.t.sf(t, nb - 1))
    p = min(1.0, 2.0 * min(p_mean, signed_rank_p(means))) if robust else p_mean
    return t, p, p_mean


def signed_rank_p(means) -> float:
    """One-sided Wilcoxon signed-rank p that the block means are above zero (blocks with a
    mean of exactly zero, e.g. masked out, are dropped); 1.0 with fewer than 3 left.

    >>> bool(signed_rank_p(np.r_[np.linspace(0.01, 0.02, 20), -1.0]) < 1e-3)  # one big swing: still better
    True
    >>> signed_rank_p([0.0, 0.0, 0.5])
    1.0
    """
    m = np.asarray(means, dtype=float)
    m = m[m != 0]
    if len(m) < 3:
        return 1.0
    return float(scipy.stats.wilcoxon(m, alternative="greater").pvalue)


# rounding of the scores written to diagnosis.json


def _r(x, nd=4):
    x = float(x)
    return None if not np.isfinite(x) else round(x, nd)


def _g(x):
    """Three significant digits (p-values)."""
    x = float(x)
    return None if not np.isfinite(x) else float(f"{x:.3g}")
