"""The fast fit paths against their references: WLS as one GEMM (issue 13) and NLS on the
compressed residual."""

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
import pytest

from hapid.fit import OMEGA_C_PAPER, paper_weight, wls, wls_coefficients
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
    for got, want in ((m[:, 0], one.hand.M), (b[:, 1], one.total.B), (k[:, 1], one.total.K)):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-12,
                                   atol=1e-12 * float(jnp.max(jnp.abs(want))))  # fmt: skip
