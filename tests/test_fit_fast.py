"""The fast fit paths against their references: WLS as one GEMM (issue 13) and NLS on the
compressed residual."""

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
import pytest

from hapid.fit import OMEGA_C_PAPER, paper_weight, wls, wls_batch_coefficients, wls_coefficients
from hapid.fit._checks import band_mask


def _cho_solve_wls(omega, Z, omega_c, mask):
    """The previous formulation: Cholesky solve of the normal equations with every
    element as a right-hand side (the reference the GEMM form must reproduce)."""
    s = 1j * omega
    h = paper_weight(omega, omega_c) * mask
    A = h[:, None] * jnp.stack([s**2, s, jnp.ones_like(s)], axis=-1)
    c = jnp.linalg.norm(A, axis=0)
    A_s = A / c
    G = jnp.real(jnp.conj(A_s).T @ A_s)
    flat = Z.reshape(Z.shape[0], -1)
    rhs = jnp.real(jnp.conj(A_s).T @ (h[:, None] * flat))
    theta = jsl.cho_solve(jsl.cho_factor(G, lower=True), rhs) / c[:, None]
    return theta.reshape((3,) + Z.shape[1:])


@pytest.mark.parametrize("n,N,f_max", [(3, 17, None), (5, 28, 40.0), (7, 60, 25.0)])
def test_wls_gemm_equals_cholesky_form_and_lstsq(n, N, f_max):
    """Random FRFs (4 of them on one grid, frequency first): the one-matmul WLS equals the
    Cholesky form to 1e-12 and numpy lstsq per element (stacked real system)."""
    rng = np.random.default_rng(n)
    f = np.sort(rng.uniform(0.5, 80.0, N))
    w = 2 * np.pi * f
    Z = rng.standard_normal((N, 4, 2, n, n)) + 1j * rng.standard_normal((N, 4, 2, n, n))
    Z *= (1 + w**2)[:, None, None, None, None]
    mask = np.ones(N) if f_max is None else (f <= f_max).astype(float)
    got = np.asarray(wls_coefficients(jnp.asarray(w), jnp.asarray(Z), OMEGA_C_PAPER, mask))
    ref = np.asarray(_cho_solve_wls(jnp.asarray(w), jnp.asarray(Z), OMEGA_C_PAPER, mask))
    scale = np.abs(ref).reshape(3, -1).max(axis=1)[:, None, None, None, None]
    assert np.max(np.abs(got - ref) / scale) < 1e-12
    keep = mask > 0
    s = 1j * w[keep]
    h = 1.0 / (s + OMEGA_C_PAPER) ** 2
    A = h[:, None] * np.stack([s**2, s, np.ones_like(s)], axis=1)
    A_real = np.vstack([A.real, A.imag])
    flat = Z[keep].reshape(int(keep.sum()), -1)
    for e in rng.choice(flat.shape[1], 12, replace=False):
        z = h * flat[:, e]
        theta = np.linalg.lstsq(A_real, np.concatenate([z.real, z.imag]), rcond=None)[0]
        np.testing.assert_allclose(got.reshape(3, -1)[:, e], theta, rtol=1e-8,
                                   atol=1e-10 * np.abs(theta).max())  # fmt: skip


def test_wls_batch_on_shared_grid_equals_per_frf_wls():
    """``wls_coefficients`` on a frequency-first batch = ``wls`` of each FRF (1e-12)."""
    from helpers_fit import batch_frfs, random_truth

    frfs = batch_frfs(random_truth(4, seed=2), 5, rel_noise=1e-2)
    one = jax.vmap(lambda f: wls(f, f_max_hz=40.0))(frfs)
    Z = jnp.stack([frfs.Z_H, frfs.Z_T], axis=1)  # (B, 2, N, n, n)
    Z = jnp.moveaxis(Z, 2, 0)  # (N, B, 2, n, n)
    mask = band_mask(frfs.omega[0], 40.0)
    m, b, k = wls_coefficients(frfs.omega[0], Z, OMEGA_C_PAPER, mask)
    Zb = jnp.stack([frfs.Z_H, frfs.Z_T], axis=2)  # (B, N, 2, n, n), batch first
    th = wls_batch_coefficients(frfs.omega[0], Zb, OMEGA_C_PAPER, mask).reshape(
        (Zb.shape[0], 3) + Zb.shape[2:]
    )
    for got, want in ((m[:, 0], one.hand.M), (b[:, 1], one.total.B), (k[:, 1], one.total.K),
                      (th[:, 0, 0], one.hand.M), (th[:, 1, 0], one.hand.B),
                      (th[:, 2, 1], one.total.K)):  # fmt: skip
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-12,
                                   atol=1e-12 * float(jnp.max(jnp.abs(want))))  # fmt: skip


@pytest.mark.parametrize("n,N,f_max", [(3, 17, None), (5, 28, 40.0), (4, 70, 25.0)])
def test_wls_batch_coefficients_equal_the_cholesky_form(n, N, f_max):
    """The batch-first real-part kernel (N ≤ 64: unrolled fused pass; N = 70: the GEMM
    fallback) equals the Cholesky form of the normal equations to 1e-12, called on its own
    (its own program) and traced inside a caller's jit (inlined), on random FRFs with a band."""
    rng = np.random.default_rng(10 + n)
    f = np.sort(rng.uniform(0.5, 80.0, N))
    w = 2 * np.pi * f
    B = 3
    Z = rng.standard_normal((B, N, 2, n, n)) + 1j * rng.standard_normal((B, N, 2, n, n))
    Z *= (1 + w**2)[None, :, None, None, None]
    mask = None if f_max is None else (f <= f_max).astype(float)
    ref = _cho_solve_wls(jnp.asarray(w), jnp.asarray(np.moveaxis(Z, 1, 0)), OMEGA_C_PAPER,
                         np.ones(N) if mask is None else mask)  # fmt: skip
    ref = np.moveaxis(np.asarray(ref), 0, 1).reshape(B, 3, -1)  # (B, 3, 2n²)
    scale = np.abs(ref).max(axis=(0, 2))[None, :, None]
    own = np.asarray(wls_batch_coefficients(jnp.asarray(w), jnp.asarray(Z), OMEGA_C_PAPER, mask))
    traced = jax.jit(lambda w_, Z_: wls_batch_coefficients(w_, Z_, OMEGA_C_PAPER, mask))
    inl = np.asarray(traced(jnp.asarray(w), jnp.asarray(Z)))
    assert own.shape == (B, 3, 2 * n * n)
    assert np.max(np.abs(own - ref) / scale) < 1e-12
    assert np.max(np.abs(inl - ref) / scale) < 1e-12


def test_wls_batch_coefficients_rejects_a_grid_of_the_wrong_length():
    with pytest.raises(ValueError, match=r"\(B, N, \.\.\.\) with N = len\(omega\) = 5"):
        wls_batch_coefficients(jnp.linspace(1.0, 5.0, 5), jnp.ones((2, 4, 3, 3), complex))


@pytest.mark.parametrize(
    "weight,f_max,n",
    [("relative", 40.0, 3), ("paper", None, 4), ("blend", 30.0, 3)],
)
def test_compressed_residual_has_the_full_cost_gradient_and_gauss_newton_matrix(weight, f_max, n):
    """The QR-compressed residual (what the solver and the Laplace covariance use) against
    the full weighted residual at a random θ: same ½‖r‖², same Jᵀr and JᵀJ (jax.jacfwd of
    the full residual), and its own Jacobian equals central finite differences."""
    from helpers_fit import random_truth, synthetic_frf

    from hapid.fit import make_problem, n_params
    from hapid.fit._compress import compress

    frf = synthetic_frf(random_truth(n, seed=30 + n), rel_noise=1e-2, seed=31)
    full = make_problem(frf, weight=weight, f_max_hz=f_max)
    comp = compress(full)
    theta = jnp.asarray(np.random.default_rng(n).standard_normal(n_params(n)))

    @jax.jit
    def both(theta):
        return full.cost(theta), comp.cost(theta), jax.jacfwd(full)(theta), full(theta)

    @jax.jit
    def comp_jac(theta):
        return jax.jacfwd(comp)(theta), comp(theta)

    c_f, c_c, Jf, r_f = both(theta)
    Jc, r_c = comp_jac(theta)
    assert r_c.shape == (6 * n * (n + 1) // 2 + 1,)
    np.testing.assert_allclose(float(c_c), float(c_f), rtol=1e-11)
    g_f, g_c = Jf.T @ r_f, Jc.T @ r_c
    np.testing.assert_allclose(
        np.asarray(g_c), np.asarray(g_f), atol=1e-10 * float(jnp.max(jnp.abs(g_f)))
    )
    H_f, H_c = Jf.T @ Jf, Jc.T @ Jc
    np.testing.assert_allclose(
        np.asarray(H_c), np.asarray(H_f), atol=1e-10 * float(jnp.max(jnp.abs(H_f)))
    )
    h = 1e-6
    cj = jax.jit(lambda t: comp(t))
    for q in (0, n_params(n) // 2, n_params(n) - 1):
        e = jnp.zeros_like(theta).at[q].set(h)
        fd = (cj(theta + e) - cj(theta - e)) / (2 * h)
        np.testing.assert_allclose(
            np.asarray(Jc[:, q]), np.asarray(fd), atol=1e-6 * float(jnp.max(jnp.abs(Jc)))
        )


def test_fit_nls_on_compressed_residual_reaches_the_full_residual_optimum():
    """The fit (compressed residual) ends where the full residual is stationary: its
    gradient, by jax.grad of the full cost, is ~0 relative to the starting one; the reported
    cost is the full cost."""
    from helpers_fit import random_truth, synthetic_frf

    from hapid.fit import fit_nls, make_problem

    frf = synthetic_frf(random_truth(3, seed=5), rel_noise=1e-2, seed=6)
    res = fit_nls(frf, f_max_hz=40.0)
    assert res.ok
    full = make_problem(frf, f_max_hz=40.0, scale=res.scale)
    np.testing.assert_allclose(float(full.cost(res.theta)), float(res.cost), rtol=1e-12)
    g = jax.grad(full.cost)(res.theta)
    assert float(jnp.linalg.norm(g)) < 1e-6 * max(1.0, float(res.cost))
