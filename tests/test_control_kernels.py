"""XLA small-matrix kernels (hapid.control._kernels) against numpy/LAPACK."""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid.control import _kernels as K


def _cases(n, rng, B=64):
    """Random complex, clustered (g·I + small), defective-ish (Jordan blocks of 2 under a
    random similarity) and triangular/diagonal matrices, ``(B, n, n)``."""
    A = rng.standard_normal((B, n, n)) + 1j * rng.standard_normal((B, n, n))
    g = rng.standard_normal((B, 1, 1)) + 1j * rng.standard_normal((B, 1, 1))
    clustered = g * np.eye(n) + 1e-6 * A
    J = np.zeros((B, n, n), complex)
    lam = rng.standard_normal((B, (n + 1) // 2)) + 1j * rng.standard_normal((B, (n + 1) // 2))
    for i in range(n):
        J[:, i, i] = lam[:, i // 2]
        if i % 2 == 1:
            J[:, i - 1, i] = 1.0
    R = rng.standard_normal((B, n, n)) + np.eye(n) * 3
    defective = R @ J @ np.linalg.inv(R)
    tri = np.triu(A)
    diag = A * np.eye(n)
    return {"random": A, "clustered": clustered, "defective": defective, "triangular": tri,
            "diagonal": diag}  # fmt: skip


def _match_err(e, r):
    """Largest distance from an eigenvalue of ``r`` to its optimally matched one of ``e``
    (per matrix, rows ``(B, n)``)."""
    n = e.shape[1]
    perms = np.array(list(itertools.permutations(range(n))))
    d = np.abs(e[:, perms] - r[:, None, :])  # (B, P, n)
    return np.min(np.max(d, axis=2), axis=1)


def _check_eigvals(n, seed):
    rng = np.random.default_rng(seed)
    cases = _cases(n, rng, B=60)
    A = np.concatenate(list(cases.values()))
    # the program of tests/test_kernels_eig.py (jit of eigvals on 300 matrices): one compile
    # per n between the two files (the persistent cache holds it)
    e = np.asarray(jax.jit(K.eigvals)(K.to_entries(jnp.asarray(A)))).T
    r = np.linalg.eigvals(A)
    scale = np.linalg.norm(A, axis=(1, 2))
    err = _match_err(e, r) / scale
    B = len(cases["random"])
    for k, name in enumerate(cases):
        tol = 1e-6 if name == "defective" else 1e-12  # double eigenvalue: error ~ √ε·‖A‖
        assert np.max(err[k * B : (k + 1) * B]) < tol, (n, name, np.max(err[k * B : (k + 1) * B]))


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_eigvals_equal_lapack(n):
    _check_eigvals(n, seed=n)


@pytest.mark.slow  # the n = 6 program compiles in ~25 s
def test_eigvals_equal_lapack_n6():
    _check_eigvals(6, seed=6)


@pytest.mark.parametrize("n", [7, 8])
def test_eigvals_above_the_unrolled_size_use_lapack(n):
    rng = np.random.default_rng(n)
    A = rng.standard_normal((5, n, n)) + 1j * rng.standard_normal((5, n, n))
    e = np.asarray(K.eigvals(K.to_entries(jnp.asarray(A)))).T
    assert np.max(_match_err(e, np.linalg.eigvals(A))) < 1e-10


def test_eigvals_of_nonfinite_matrices_terminate():
    A = np.full((3, 3, 300), np.nan + 0j)  # the n = 3 program of test_eigvals_equal_lapack
    e = np.asarray(jax.jit(K.eigvals)(jnp.asarray(A)))
    assert e.shape == (3, 300) and not np.all(np.isfinite(e))


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_pair_optimal_is_the_best_permutation(n):
    rng = np.random.default_rng(10 + n)
    I = 400  # the jitted program of tests/test_kernels_eig.py (eager there for n ≤ 2)
    a = rng.standard_normal((n, I)) + 1j * rng.standard_normal((n, I))
    b = a + 0.8 * (rng.standard_normal((n, I)) + 1j * rng.standard_normal((n, I)))
    got = np.asarray(jax.jit(K.pair_optimal)(jnp.asarray(a), jnp.asarray(b)))
    perms = np.array(list(itertools.permutations(range(n))))
    cost = np.sum(np.abs(a.T[:, None, :] - b.T[:, perms]) ** 2, axis=2)  # (I, P)
    best = b.T[np.arange(I)[:, None], perms[np.argmin(cost, axis=1)]]
    np.testing.assert_array_equal(got.T, best)


def test_det_inv_and_sigma_max_equal_lapack():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((200, 4, 4)) + 1j * rng.standard_normal((200, 4, 4))
    E = K.to_entries(jnp.asarray(A))  # jitted, as the loop analysis runs them (not op by op)
    det, Ai = jax.jit(functools.partial(K.det_inv, unroll=True))(E)
    np.testing.assert_allclose(np.asarray(det), np.linalg.det(A), rtol=1e-11)
    np.testing.assert_allclose(np.asarray(K.from_entries(Ai)), np.linalg.inv(A), rtol=1e-9,
                               atol=1e-10 * np.abs(np.linalg.inv(A)).max())  # fmt: skip
    s = np.asarray(jax.jit(K.sigma_max)(E))
    np.testing.assert_allclose(s, np.linalg.svd(A, compute_uv=False)[:, 0], rtol=1e-12)
    lo, hi = jax.jit(K.sigma_bounds)(E)
    assert np.all(np.asarray(lo) <= s * (1 + 1e-12)) and np.all(s <= np.asarray(hi) * (1 + 1e-12))


def test_det_inv_screened_equals_numpy_with_and_without_row_exchanges():
    """The whole-grid det/inverse (no row exchanges where every pivot passes the threshold
    test, partial pivoting for the rest): numpy's det and inv, on a batch mixing diagonally
    dominant matrices (the fast path), random ones and matrices whose first pivot is zero
    or tiny (which need row exchanges), and a singular one (det 0, non-finite inverse)."""
    rng = np.random.default_rng(11)
    n, B = 5, 700
    A = rng.standard_normal((B, n, n)) + 1j * rng.standard_normal((B, n, n))
    A[:300] = 0.05 * A[:300] + 4.0 * np.eye(n)  # dominant: no exchanges needed
    A[300:350, 0, 0] = 0.0  # zero first pivot
    A[350:400, 1, 1] = 1e-9 * A[350:400, 1, 1]
    A[400:450] = A[400:450][:, [3, 0, 4, 1, 2]]  # permuted rows of random matrices
    A[-1, 2] = A[-1, 4]  # singular
    det, S = jax.jit(K.det_inv_screened)(K.to_entries(jnp.asarray(A)))
    det, S = np.asarray(det), np.asarray(K.from_entries(S))
    ok = np.arange(B) < B - 1
    np.testing.assert_allclose(det[ok], np.linalg.det(A[ok]), rtol=1e-11)
    np.testing.assert_allclose(S[ok], np.linalg.inv(A[ok]), rtol=1e-9, atol=1e-11)
    assert abs(det[-1]) < 1e-10 * np.abs(A[-1]).max() ** n
