"""WLS baseline (paper section 4.2) against independent references, and recovery."""

import jax
import numpy as np
import pytest
import scipy.linalg
from helpers_fit import PAPER_FREQ_HZ, batch_frfs, random_truth, synthetic_frf, wls_reference

from hapid.fit import model_relative_errors, wls


@pytest.mark.parametrize("n", [3, 5, 6])
def test_wls_equals_loop_reference(n):
    truth = random_truth(n, seed=n)
    frf = synthetic_frf(truth, rel_noise=1e-2, seed=n + 10)
    model = wls(frf)
    f = np.asarray(frf.freq_hz)
    for Z, so in ((frf.Z_H, model.hand), (frf.Z_T, model.total)):
        ref = wls_reference(f, np.asarray(Z))
        for k, A in enumerate((so.M, so.B, so.K)):
            np.testing.assert_allclose(
                np.asarray(A), ref[k], rtol=1e-10, atol=1e-10 * np.abs(ref[k]).max()
            )


@pytest.mark.parametrize("omega_c", [7 * 2 * np.pi, 2 * np.pi * 2.0])
def test_wls_band_and_corner_equal_reference(omega_c):
    truth = random_truth(4, seed=3)
    frf = synthetic_frf(truth, rel_noise=1e-2, seed=4)
    model = wls(frf, omega_c=omega_c, f_max_hz=40.0)
    keep = np.asarray(frf.freq_hz) <= 40.0
    ref = wls_reference(np.asarray(frf.freq_hz)[keep], np.asarray(frf.Z_T)[keep], omega_c)
    for k, A in enumerate((model.total.M, model.total.B, model.total.K)):
        np.testing.assert_allclose(
            np.asarray(A), ref[k], rtol=1e-10, atol=1e-10 * np.abs(ref[k]).max()
        )


def test_wls_equals_scipy_lstsq_on_stacked_real_system():
    n = 3
    frf = synthetic_frf(random_truth(n, seed=7), rel_noise=1e-2, seed=8)
    model = wls(frf)
    w = np.asarray(frf.omega)
    s = 1j * w
    h = 1.0 / (s + 7 * 2 * np.pi) ** 2
    A = h[:, None] * np.stack([s**2, s, np.ones_like(s)], axis=1)
    A_real = np.vstack([A.real, A.imag])
    Z = np.asarray(frf.Z_H)
    for i in range(n):
        for j in range(n):
            z = h * Z[:, i, j]
            theta, *_ = scipy.linalg.lstsq(A_real, np.concatenate([z.real, z.imag]))
            got = np.array([model.hand.M[i, j], model.hand.B[i, j], model.hand.K[i, j]])
            np.testing.assert_allclose(got, theta, rtol=1e-9)


@pytest.mark.parametrize("n", [3, 5, 6])
def test_wls_recovers_second_order_truth(n):
    truth = random_truth(n, seed=20 + n)
    frf = synthetic_frf(truth, PAPER_FREQ_HZ, rel_noise=1e-4, seed=n)
    err = np.asarray(model_relative_errors(wls(frf), truth))
    assert err.max() < 5e-3, err


def test_wls_jit_and_vmap_equal_singles():
    truth = random_truth(3, seed=1)
    batch = batch_frfs(truth, 4, rel_noise=1e-3)
    out = jax.jit(jax.vmap(wls))(batch)
    for k in range(4):
        single = wls(jax.tree_util.tree_map(lambda a, k=k: a[k], batch))
        np.testing.assert_allclose(
            np.asarray(out.total.K[k]), np.asarray(single.total.K), rtol=1e-12
        )
        np.testing.assert_allclose(np.asarray(out.hand.M[k]), np.asarray(single.hand.M), rtol=1e-12)
