"""The subspace step's factor from the Gram matrix of the block Hankel matrix (lpvpc.identification.subspace.
moesp_factor, hankel_gram; lpvpc.linalg.deflated_cholesky) against a QR of the matrix itself."""

from __future__ import annotations

import numpy as np
import pytest

from lpvpc import linalg
from lpvpc.linalg import DEFLATE_TOL, deflated_cholesky
from lpvpc.io.segments import Segments
from lpvpc.identification.subspace import hankel_gram, hankel_rows, moesp_factor, po_moesp, streamed_r


@pytest.fixture(autouse=True)
def gram_at_any_size(monkeypatch):
    """These matrices are small, where moesp_factor would take the QR for speed alone."""
    import lpvpc.identification.subspace

    monkeypatch.setattr(lpvpc.identification.subspace, "GRAM_MIN_WORK", 0)


def _hankel(u_f, u_p, y, s, seg=None):
    seg = seg or [(0, len(y))]
    return np.vstack([hankel_rows(u_f[a:b], u_p[a:b], y[a:b], 0, (b - a) - 2 * s + 1, s)
                      for a, b in seg if (b - a) - 2 * s + 1 > 0])


def _l32_svd(R, s, n_f, n_p):
    """What MOESP takes from the factor: the SVD of the future outputs' past-data block."""
    L = R.T
    U, sv, _ = np.linalg.svd(L[s * (n_f + n_p + 1):, s * n_f: s * (n_f + n_p + 1)])
    return U * np.sign(U[np.argmax(np.abs(U), axis=0), np.arange(U.shape[1])]), sv


def _lpv_like(n, seed):
    """Inputs with the LPV regressors' structure: a constant, a slowly varying scheduling
    function (rho holds levels), a lagged position times it, and a velocity-like input;
    y a filtered mix plus noise."""
    rng = np.random.default_rng(seed)
    p = np.repeat(rng.uniform(-1, 1, n // 5 + 1), 5)[:n]
    rho = np.repeat(rng.uniform(-1, 1, n // 400 + 1), 400)[:n] + 1e-3 * np.sin(np.arange(n) / 50)
    lag = np.r_[0.0, p[:-1]]
    u = np.column_stack([np.ones(n), rho, rho ** 2, p * rho, lag * rho, np.r_[0.0, np.diff(p)]])
    y = np.convolve(u @ rng.standard_normal(u.shape[1]), 0.8 ** np.arange(30))[:n] + 0.1 * rng.standard_normal(n)
    return u, y


def test_hankel_gram_equals_the_gram_matrix_of_the_rows_trial_by_trial():
    rng = np.random.default_rng(1)
    u, y = rng.standard_normal((260, 3)), rng.standard_normal(260)
    s = 3
    seg = Segments([(0, 120), (120, 124), (124, 260)], 260)  # the middle trial is too short for a row
    H = _hankel(u, u[:, :2], y, s, list(seg))
    blocks = [([0, 1, 2], i) for i in range(s, 2 * s)] + [([0, 1], i) for i in range(s)] + [([3], i) for i in range(2 * s)]
    G = hankel_gram(np.column_stack([u, y]), blocks, seg)
    np.testing.assert_allclose(G, H.T @ H, rtol=1e-12, atol=1e-10 * np.abs(G).max())


def test_gram_factor_equals_the_qr_factor_up_to_row_signs():
    rng = np.random.default_rng(2)
    u, y = rng.standard_normal((3000, 4)), rng.standard_normal(3000)
    s = 4
    R, how = moesp_factor(u, u[:, :2], y, s)
    R_qr = streamed_r(u, u[:, :2], y, s)
    assert how == "gram"
    np.testing.assert_allclose(np.abs(R), np.abs(R_qr), atol=1e-9 * np.abs(R_qr).max())


def test_dependent_columns_get_zero_rows_and_leave_the_subspace_of_the_independent_ones():
    # A constant input repeats at every shift, a lagged input times rho reappears one shift
    # later, rho nearly repeats: the Gram route keeps only what the independent columns
    # determine, which a QR of the independent columns alone gives to 1e-8.
    u, y = _lpv_like(6000, 3)
    s, n_p = 5, 3
    R, how = moesp_factor(u, u[:, :n_p], y, s)
    assert how == "gram"
    H = _hankel(u, u[:, :n_p], y, s)
    np.testing.assert_allclose(R.T @ R, H.T @ H, atol=1e-10 * np.abs(H.T @ H).max())
    zero = np.all(R == 0, axis=1)
    assert zero[s * u.shape[1]:].sum() >= s - 1  # the past constant repeats the future one
    kept = ~zero
    Q = np.linalg.qr(H[:, kept])[0]
    R_ref = np.zeros_like(R)
    R_ref[kept] = Q.T @ H
    (U, sv), (U_ref, sv_ref) = _l32_svd(R, s, u.shape[1], n_p), _l32_svd(R_ref, s, u.shape[1], n_p)
    np.testing.assert_allclose(sv, sv_ref, rtol=1e-8)
    np.testing.assert_allclose(U[:, :3], U_ref[:, :3], atol=1e-8)


def test_an_ill_conditioned_hankel_matrix_falls_back_to_qr():
    # Powers 0..15 of a ramp: cond ~1e12 and more, squared by the Gram matrix; its
    # Cholesky factor fails the check (lpvpc.linalg.gram_factor_ok) and the QR is used.
    rng = np.random.default_rng(4)
    x = np.linspace(0.0, 1.0, 2000)
    u = np.column_stack([x ** j for j in range(16)] + [rng.standard_normal(2000)])
    y = rng.standard_normal(2000)
    R, how = moesp_factor(u, u[:, -1:], y, 3)
    assert how == "qr"
    np.testing.assert_array_equal(R, streamed_r(u, u[:, -1:], y, 3))
    assert po_moesp(u[:, -1:], u[:, :-1], y, 3).factorisation == "qr"  # po_moesp says which route it took
    # near-dependent inputs (1e-7 of noise on combinations of three): their pivots are
    # roundoff-sized, and the factor grown through them fails the check as well
    base = rng.standard_normal((2000, 3))
    u = np.column_stack([base, base @ rng.standard_normal((3, 8)) + 1e-7 * rng.standard_normal((2000, 8))])
    assert moesp_factor(u, u[:, :1], y, 3)[1] == "qr"
    assert po_moesp(rng.standard_normal((2000, 1)), rng.standard_normal((2000, 2)), y, 3).factorisation == "gram"


def test_deflated_cholesky_of_a_semidefinite_matrix():
    rng = np.random.default_rng(5)
    M = rng.standard_normal((500, 150))
    M[:, 70] = M[:, 3] - 2 * M[:, 60]  # exactly dependent on earlier columns (across the 64-column blocks)
    M[:, 140] = M[:, 139]
    G = M.T @ M
    R, pivots = deflated_cholesky(G, block=64)
    assert set(np.flatnonzero(pivots <= DEFLATE_TOL)) == {70, 140}
    assert np.all(R[[70, 140]] == 0) and np.allclose(np.triu(R), R)
    np.testing.assert_allclose(R.T @ R, G, atol=1e-10 * np.abs(G).max())
    assert linalg.gram_factor_ok(G, R, pivots)
    R[70, 0] = 1e-3  # a factor that does not reproduce G is refused
    assert not linalg.gram_factor_ok(G, R, pivots)


@pytest.mark.parametrize("seed", [0, 1])
def test_po_moesp_poles_do_not_depend_on_the_route(seed, monkeypatch):
    # The same data through the Gram and the QR routes (forced): the same singular values
    # and poles (the dependent constant columns' rows are zero in one, arbitrary directions
    # of the complement in the other, so compare on data without exact repeats).
    import lpvpc.identification.subspace as subspace

    rng = np.random.default_rng(seed)
    u = rng.standard_normal((4000, 2))
    y = np.convolve(u[:, 0] - 0.5 * u[:, 1], 0.9 ** np.arange(60))[:4000] + 0.05 * rng.standard_normal(4000)
    gram = po_moesp(u[:, :1], u[:, 1:], y, 6)
    monkeypatch.setattr(subspace, "gram_factor_ok", lambda *args: False)
    qr = po_moesp(u[:, :1], u[:, 1:], y, 6)
    assert (gram.factorisation, qr.factorisation) == ("gram", "qr")
    np.testing.assert_allclose(gram.singular_values, qr.singular_values, rtol=1e-9)
    A_g, _ = gram.system(2)
    A_q, _ = qr.system(2)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(A_g).real), np.sort(np.linalg.eigvals(A_q).real), rtol=1e-9)
