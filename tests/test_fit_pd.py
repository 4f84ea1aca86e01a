"""The PD parameterization: θ ↔ model, projection, boundary report."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers_fit import random_truth

from hapid.fit import (
    MATRIX_NAMES,
    Scale,
    boundary_names,
    boundary_report,
    canonical_theta,
    model_to_theta,
    n_params,
    project_pd,
    theta_to_model,
)
from hapid.impedance import ImpedanceModel, SecondOrder


def _mats(m):
    return [m.hand.M, m.hand.B, m.hand.K, m.mechanism.M, m.mechanism.B, m.mechanism.K]


@pytest.mark.parametrize("n", [3, 5, 6])
def test_roundtrip_and_length(n):
    truth = random_truth(n, seed=n)
    scale = Scale(jnp.asarray(2 * np.pi * 8.0), jnp.asarray(300.0))
    theta = model_to_theta(truth, scale)
    assert theta.shape == (n_params(n),) == (6 * n * (n + 1) // 2,)
    back = theta_to_model(theta, scale)
    for a, b in zip(_mats(back), _mats(truth), strict=True):
        np.testing.assert_allclose(
            np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-10 * np.abs(b).max()
        )


def test_any_theta_gives_symmetric_psd_and_free_sign_diagonal():
    n = 4
    theta = jax.random.normal(jax.random.PRNGKey(0), (n_params(n),))
    model = theta_to_model(theta)
    for A in _mats(model):
        A = np.asarray(A)
        np.testing.assert_allclose(A, A.T, atol=1e-12)
        assert np.linalg.eigvalsh(A).min() > -1e-12
    # flipping column signs of L (the diagonal's sign is free) leaves the model unchanged
    same = theta_to_model(canonical_theta(theta))
    for a, b in zip(_mats(same), _mats(model), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-12)
    assert not np.allclose(canonical_theta(theta), theta)


def test_project_pd_symmetrizes_and_clips():
    rng = np.random.default_rng(0)
    n = 3
    A = rng.standard_normal((n, n))
    so = SecondOrder(jnp.asarray(A), jnp.asarray(A @ A.T), jnp.asarray(-A @ A.T))
    model = ImpedanceModel.from_hand_mechanism(so, so)
    proj = project_pd(model, floor=1e-3)
    for P in _mats(proj):
        P = np.asarray(P)
        np.testing.assert_allclose(P, P.T, atol=1e-12)
        lam = np.linalg.eigvalsh(P)
        assert lam.min() >= 1e-3 * np.abs(lam).max() * (1 - 1e-9)
    np.testing.assert_allclose(np.asarray(proj.total.M), np.asarray(proj.hand.M + proj.mechanism.M))
    # PD input is unchanged
    truth = random_truth(3, 1)
    for a, b in zip(_mats(project_pd(truth)), _mats(truth), strict=True):
        np.testing.assert_allclose(
            np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-10 * np.abs(b).max()
        )


def test_boundary_report():
    truth = random_truth(3, 2)
    flags = np.asarray(boundary_report(truth))
    assert not flags.any()
    zero_k = ImpedanceModel.from_hand_mechanism(
        truth.hand, SecondOrder(truth.mechanism.M, truth.mechanism.B, jnp.zeros((3, 3)))
    )
    assert boundary_names(boundary_report(zero_k)) == ["K_M"]
    assert MATRIX_NAMES[5] == "K_M"


def test_bad_theta_length():
    with pytest.raises(ValueError, match="6·n"):
        theta_to_model(jnp.zeros(7))
