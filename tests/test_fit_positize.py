"""Positizing (paper section 5.1) and the closed-RHP root check."""

import jax.numpy as jnp
import numpy as np
import pytest
from helpers_fit import random_truth, synthetic_frf

from hapid.fit import crhp_report, positize, positize_matrix, wls
from hapid.impedance import ImpedanceModel, SecondOrder


def _real_eig_matrix(rng, n):
    V = rng.standard_normal((n, n)) + 2 * np.eye(n)
    D = rng.uniform(-3.0, 3.0, n)
    return V @ np.diag(D) @ np.linalg.inv(V)


@pytest.mark.parametrize("mode", ["modulus", "real_part"])
def test_real_eigenvalues_equal_numpy_V_absD_Vinv(mode):
    rng = np.random.default_rng(0)
    for n in (3, 5, 6):
        A = _real_eig_matrix(rng, n)
        lam, V = np.linalg.eig(A)
        assert np.allclose(lam.imag, 0)
        ref = (V @ np.diag(np.abs(lam)) @ np.linalg.inv(V)).real
        got = np.asarray(positize_matrix(jnp.asarray(A), mode))
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_symmetric_matrix_gives_matrix_absolute_value():
    rng = np.random.default_rng(1)
    Q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    A = Q @ np.diag([-2.0, -0.5, 1.0, 3.0]) @ Q.T
    got = np.asarray(positize_matrix(jnp.asarray(A)))
    np.testing.assert_allclose(got, Q @ np.diag([2.0, 0.5, 1.0, 3.0]) @ Q.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(0.5 * (got + got.T)) > 0)


def test_complex_eigenvalues_documented_treatment():
    rng = np.random.default_rng(2)
    A = rng.standard_normal((5, 5))
    lam, V = np.linalg.eig(A)
    assert np.any(np.abs(lam.imag) > 1e-3)  # has a complex pair
    # paper-literal modulus: V|D|V⁻¹ is real up to rounding; we return its real part
    full = V @ np.diag(np.abs(lam)) @ np.linalg.inv(V)
    assert np.abs(full.imag).max() < 1e-10 * np.abs(full).max()
    np.testing.assert_allclose(np.asarray(positize_matrix(jnp.asarray(A))), full.real, atol=1e-10)
    # real_part mode: λ → |Re λ| + j Im λ, also real, keeps the imaginary parts
    g = np.abs(lam.real) + 1j * lam.imag
    full2 = V @ np.diag(g) @ np.linalg.inv(V)
    assert np.abs(full2.imag).max() < 1e-10 * np.abs(full2).max()
    got2 = np.asarray(positize_matrix(jnp.asarray(A), "real_part"))
    np.testing.assert_allclose(got2, full2.real, atol=1e-10)
    np.testing.assert_allclose(
        np.sort_complex(np.linalg.eigvals(got2)), np.sort_complex(g), atol=1e-9
    )


def test_positize_removes_crhp_roots():
    truth = random_truth(3, seed=5)
    # flip the sign of one stiffness and one damping eigen-direction: roots in the RHP
    K = np.asarray(truth.hand.K)
    lam, Q = np.linalg.eigh(K)
    K_bad = Q @ np.diag(lam * np.array([-1, 1, 1])) @ Q.T
    B = np.asarray(truth.total.B)
    lamb, Qb = np.linalg.eigh(B)
    B_bad = Qb @ np.diag(lamb * np.array([1, -1, 1])) @ Qb.T
    bad = ImpedanceModel(
        hand=SecondOrder(truth.hand.M, truth.hand.B, jnp.asarray(K_bad)),
        total=SecondOrder(truth.total.M, jnp.asarray(B_bad), truth.total.K),
    )
    before = crhp_report(bad)
    assert int(before.hand) > 0 and int(before.total) > 0
    after = crhp_report(positize(bad))
    assert int(after.hand) < int(before.hand) and int(after.total) < int(before.total)
    assert bool(after.ok)


def test_positize_keeps_a_good_wls_model_and_counts_roots():
    truth = random_truth(5, seed=9)
    model = wls(synthetic_frf(truth, rel_noise=1e-4))
    assert bool(crhp_report(model).ok)
    pos = positize(model)
    # all M, B, K of a good fit already have positive real eigenvalues: positizing is ~identity
    np.testing.assert_allclose(
        np.asarray(pos.total.K), np.asarray(model.total.K), rtol=1e-8, atol=1e-8
    )
    assert bool(crhp_report(pos).ok)


def test_positize_bad_mode():
    with pytest.raises(ValueError, match="mode"):
        positize_matrix(jnp.eye(2), "abs")
