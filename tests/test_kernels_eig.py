"""Eigenvalue and pairing kernels (hapid.control._kernels.eigvals / pair_optimal) against
numpy's LAPACK ``eigvals`` and a brute-force permutation search, on the matrix families the
loop analysis meets: random, near-scalar (a well-modelled loop, L ≈ g·I), eigenvalues spread
over 1e-10 … 1e3, Jordan blocks, and the cu5 posterior loops (slow)."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid.control import _kernels as K


def _match(e, r):
    """``e`` reordered (rows ``(B, n)``) to the optimal matching with ``r``."""
    n = e.shape[1]
    perms = np.array(list(itertools.permutations(range(n))))
    d = np.max(np.abs(e[:, perms] - r[:, None, :]), axis=2)  # (B, P)
    return e[np.arange(len(e))[:, None], perms[np.argmin(d, axis=1)]]


def _family(name, n, B, rng):
    Z = rng.standard_normal((B, n, n)) + 1j * rng.standard_normal((B, n, n))
    g = (rng.standard_normal(B) + 1j * rng.standard_normal(B))[:, None, None]
    if name == "random":
        return Z
    if name == "scalar_1e-3":
        return g * np.eye(n) + 1e-3 * Z
    if name == "scalar_1e-6":
        return g * np.eye(n) + 1e-6 * Z
    if name == "spread":  # |λ| log-uniform over 1e-10 … 1e3, unitary similarity
        lam = 10 ** rng.uniform(-10, 3, (B, n)) * np.exp(2j * np.pi * rng.uniform(size=(B, n)))
        Q, _ = np.linalg.qr(Z)
        return Q @ (lam[:, :, None] * np.conj(np.swapaxes(Q, 1, 2)))
    if name == "jordan":  # one full Jordan block g·I + N, perturbed by 1e-12
        return g * np.eye(n) + np.eye(n, k=1) + 1e-12 * rng.standard_normal((B, n, n))
    raise ValueError(name)


def _eig(A):
    return np.asarray(jax.jit(K.eigvals)(K.to_entries(jnp.asarray(A)))).T


@pytest.mark.parametrize("name", ["random", "scalar_1e-3", "scalar_1e-6", "spread"])
@pytest.mark.parametrize("n", [2, 5, pytest.param(6, marks=pytest.mark.slow)])
def test_eigvals_equal_lapack_within_backward_error(name, n):
    rng = np.random.default_rng(7 * n + len(name))
    A = _family(name, n, 300, rng)
    ref = np.linalg.eigvals(A)
    got = _match(_eig(A), ref)
    tol = 1e-12 * np.linalg.norm(A, axis=(1, 2))[:, None] + 1e-10 * np.abs(ref)
    assert np.all(np.abs(got - ref) <= tol), np.max(np.abs(got - ref) / tol)


@pytest.mark.slow  # CI budget (~12 s); the random/near-scalar/spread families stay fast
def test_eigvals_of_a_jordan_block_within_its_conditioning():
    """A 5 × 5 Jordan block perturbed by δ = 1e-12 has eigenvalues ~δ^(1/5) ≈ 4e-3 from g,
    as sensitive as that: both solvers agree on the centre to rounding and on the spread
    to ε^(1/5)-level (what any backward-stable method gives)."""
    rng = np.random.default_rng(1)
    A = _family("jordan", 5, 200, rng)
    ref = np.linalg.eigvals(A)
    got = _match(_eig(A), ref)
    np.testing.assert_allclose(got.mean(axis=1), ref.mean(axis=1), rtol=0, atol=1e-13)
    assert np.max(np.abs(got - ref)) < 1e-8
    assert np.min(np.abs(ref - ref.mean(axis=1, keepdims=True))) > 1e-3  # really split


def test_eigvals_under_vmap_and_n_1():
    rng = np.random.default_rng(2)
    # n = 2: vmap does not depend on n, and the n = 2 program compiles fastest
    A = _family("random", 2, 40, rng).reshape(5, 8, 2, 2)  # (draws, freq, n, n)
    got = jax.jit(jax.vmap(lambda M: K.eigvals(K.to_entries(M))))(jnp.asarray(A))
    got = np.moveaxis(np.asarray(got), 1, -1).reshape(40, 2)
    ref = np.linalg.eigvals(A.reshape(40, 2, 2))
    np.testing.assert_allclose(_match(got, ref), ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    one = _family("random", 1, 10, rng)
    np.testing.assert_array_equal(_eig(one)[:, 0], one[:, 0, 0])


def _pair_select_chain(a, b):
    """The previous pairing (select-chain DP): the reference of the tie rule."""
    n = a.shape[0]
    d = [[jnp.abs(a[i] - b[j]) ** 2 for j in range(n)] for i in range(n)]
    f = {0: jnp.zeros(a.shape[1:], dtype=jnp.float64)}
    choice = {}
    for S in sorted(range(1, 1 << n), key=lambda s: (bin(s).count("1"), s)):
        i = bin(S).count("1") - 1
        best, arg = None, None
        for j in range(n):
            if S >> j & 1:
                c = f[S ^ (1 << j)] + d[i][j]
                if best is None:
                    best, arg = c, jnp.full(c.shape, j, dtype=jnp.int32)
                else:
                    lt = c < best
                    best, arg = jnp.where(lt, c, best), jnp.where(lt, j, arg)
        f[S], choice[S] = best, arg
    tab = jnp.stack([choice.get(S, jnp.zeros_like(choice[1])) for S in range(1 << n)])
    S = jnp.full(a.shape[1:], (1 << n) - 1, dtype=jnp.int32)
    sig = [None] * n
    for i in range(n - 1, -1, -1):
        j = jnp.take_along_axis(tab, S[None], axis=0)[0]
        sig[i] = j
        S = S - jnp.left_shift(1, j)
    return jnp.take_along_axis(b, jnp.stack(sig), axis=0)


def _perm(a, b, out):
    """The permutation σ with ``out = b[σ]`` (b's entries distinct per column here)."""
    return np.argmax(out[:, None, :] == b[None, :, :], axis=1)


@pytest.mark.parametrize("n", [1, 2, 3, 5, 6])
def test_pair_optimal_keeps_the_tie_rule_and_is_optimal(n):
    """Exact ties (small real integers: every cost is exact in any evaluation order): the same
    permutation as the previous select-chain DP (jitted; eager too for n ≤ 2), and a
    minimal cost."""
    rng = np.random.default_rng(n)
    I = 400
    a = rng.integers(0, 3, (n, I)).astype(complex)
    b = np.stack([rng.permutation(np.arange(n)) for _ in range(I)], axis=1) + 0j  # distinct
    ref = np.asarray(jax.jit(_pair_select_chain)(jnp.asarray(a), jnp.asarray(b)))
    for f in (K.pair_optimal, jax.jit(K.pair_optimal))[(n > 2) :]:
        got = np.asarray(f(jnp.asarray(a), jnp.asarray(b)))
        np.testing.assert_array_equal(_perm(a, b, got), _perm(a, b, ref))
    perms = np.array(list(itertools.permutations(range(n))))
    cost = np.sum(np.abs(a.T[:, None, :] - b.T[:, perms]) ** 2, axis=2)
    np.testing.assert_array_equal(np.sum(np.abs(a - got) ** 2, axis=0), cost.min(axis=1))


def test_pair_optimal_under_vmap():
    rng = np.random.default_rng(4)
    a = rng.standard_normal((3, 5, 50)) + 1j * rng.standard_normal((3, 5, 50))
    b = a + 0.5 * (rng.standard_normal(a.shape) + 1j * rng.standard_normal(a.shape))
    got = jax.jit(jax.vmap(K.pair_optimal))(jnp.asarray(a), jnp.asarray(b))
    one = jax.jit(K.pair_optimal)
    for d in range(3):
        np.testing.assert_array_equal(got[d], one(jnp.asarray(a[d]), jnp.asarray(b[d])))


@pytest.mark.slow
def test_eigvals_equal_lapack_on_cu5_posterior_loops():
    """The loops of the robust check: cu5, paper protocol, NLS fit, Laplace draws, the
    inverse-model controller with the paper's compensator, the posterior grid."""
    from hapid.control import Compensator, inverse_model_response
    from hapid.device import cu5
    from hapid.experiment import Protocol, estimate_frf, periodic_run
    from hapid.fit import fit_nls
    from hapid.uncertainty import laplace_samples, posterior_omega

    nls = fit_nls(estimate_frf(periodic_run(cu5(), Protocol(), noise_seed=0)))
    w = jnp.asarray(posterior_omega(1000))
    G = inverse_model_response(nls.model, Compensator.paper(), w)
    models = laplace_samples(nls, 20, key=0).models(np.arange(20))
    P = jax.jit(jax.vmap(lambda m: m.P(1j * w)))(models)
    L = np.asarray(jnp.einsum("dwij,wjk->dwik", P, G)).reshape(-1, 5, 5)
    ref = np.linalg.eigvals(L)
    got = _match(_eig(L), ref)
    tol = 1e-12 * np.linalg.norm(L, axis=(1, 2))[:, None] + 1e-10 * np.abs(ref)
    assert np.abs(ref).min() < 1e-6 * np.abs(ref).max()  # the family has a wide spread
    assert np.all(np.abs(got - ref) <= tol), np.max(np.abs(got - ref) / tol)
