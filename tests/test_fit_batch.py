"""fit_nls_batch's batched program (hapid.fit._lm_batch) against fit_nls alone (optimistix LM
through hapid.fit._iterate) and its structured pieces against autodiff / numpy (issue 13)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers_fit import random_spd, random_truth, synthetic_frf

from hapid.fit import fit_nls, fit_nls_batch, make_problem, n_params
from hapid.fit._compress import compress, lower_entries
from hapid.fit._lm_batch import (
    derivatives,
    entry_jacobian,
    gram,
    information_trace,
    inverse_information,
    jvp,
    tril_inverse,
)
from hapid.fit._nls import pinv_psd
from hapid.fit._problem import median_nonneg
from hapid.frf import as_frf
from hapid.impedance import ImpedanceModel, SecondOrder


def _rank_one_truth(n, seed):
    """A truth whose mechanism stiffness has rank 1: LM crawls toward the PSD boundary and the
    information JᵀJ of its iterates is near singular (condition > 1e10)."""
    rng = np.random.default_rng(seed)
    t = random_truth(n, seed)
    v = rng.standard_normal(n)
    mech = SecondOrder(t.mechanism.M, t.mechanism.B, 3e3 * np.outer(v, v) / (v @ v))
    hand = SecondOrder(t.hand.M, t.hand.B, random_spd(rng, n, 1e2, 1e4))
    return ImpedanceModel.from_hand_mechanism(hand, mech)


def _stack(frfs):
    f = lambda name: np.stack([np.asarray(getattr(x, name)) for x in frfs])  # noqa: E731
    return as_frf(f("freq_hz"), f("Z_H"), f("Z_T"), f("Z_H_std"), f("Z_T_std"))


def _assert_batch_equals_singles(frfs, **opts):
    batch = fit_nls_batch(_stack(frfs), **opts)
    for k, frf in enumerate(frfs):
        one = fit_nls(frf, **opts)
        assert int(batch.n_steps[k]) == int(one.n_steps)
        assert int(batch.status_code[k]) == int(one.status_code)
        np.testing.assert_allclose(float(batch.cost[k]), float(one.cost), rtol=1e-10)
        scale = float(jnp.max(jnp.abs(one.theta)))
        np.testing.assert_allclose(
            np.asarray(batch.theta[k]), np.asarray(one.theta), atol=1e-8 * scale
        )
        # the covariance is the (pseudo-)inverse of JᵀJ: both sides agree to ~cond·eps
        cov = np.asarray(one.covariance)
        lam = np.linalg.eigvalsh(cov)
        tol = 1e-12 + 1e-14 * lam[-1] / max(lam[0], 1e-300)
        np.testing.assert_allclose(
            np.asarray(batch.covariance[k]), cov, atol=tol * np.max(np.abs(cov))
        )
        np.testing.assert_allclose(float(batch.sigma2[k]), float(one.sigma2), rtol=1e-10)
        assert int(batch.n_residuals[k]) == int(one.n_residuals)
        np.testing.assert_array_equal(np.asarray(batch.at_boundary[k]), np.asarray(one.at_boundary))
        np.testing.assert_allclose(
            np.asarray(batch.model.total.K[k]),
            np.asarray(one.model.total.K),
            atol=1e-8 * float(jnp.max(jnp.abs(one.model.total.K))),
        )
        np.testing.assert_allclose(float(batch.scale.z_ref[k]), float(one.scale.z_ref), rtol=1e-15)
    return batch


def test_fit_nls_batch_equals_fit_nls_alone_including_an_ill_conditioned_fit():
    """Three regular FRFs and one of a rank-1 mechanism stiffness, stopped at max_steps with a
    near-singular JᵀJ (condition > 1e10: its covariance goes through pinv_psd, the others
    through the structured inverse): every fit of the batch takes the same steps, ends with
    the same status, cost (1e-10), θ and covariance as fit_nls alone."""
    n = 3
    frfs = [synthetic_frf(random_truth(n, seed=40), rel_noise=1e-2, seed=41 + k) for k in range(3)]
    frfs.append(synthetic_frf(_rank_one_truth(n, 7), rel_noise=1e-4, seed=44))
    batch = _assert_batch_equals_singles(frfs, f_max_hz=40.0, max_steps=60)
    assert list(batch.status) == ["converged"] * 3 + ["max_steps"]
    lam = np.linalg.eigvalsh(np.asarray(batch.covariance[3]))
    assert lam[-1] / lam[0] > 1e10  # the eigh fallback ran for this fit


@pytest.mark.slow
@pytest.mark.parametrize(
    "opts",
    [
        dict(weight="noise", f_max_hz=None),
        dict(weight="paper", f_max_hz=30.0),
        dict(weight="blend", f_max_hz=None, pd_eps=1e-3),
        dict(f_max_hz=None, max_steps=4),  # every fit stops at max_steps
    ],
)
def test_fit_nls_batch_equals_fit_nls_alone_options(opts):
    frfs = [synthetic_frf(random_truth(4, seed=50), rel_noise=1e-2, seed=51 + k) for k in range(3)]
    _assert_batch_equals_singles(frfs, **opts)


def test_structured_derivatives_equal_autodiff_and_numpy():
    """D (∂ tril(LLᵀ)/∂θ), Jᵀr, JᵀJ and Jδ of the compressed residual equal jax.jacfwd's; the
    structured (JᵀJ)⁻¹ = D⁻¹H⁻¹D⁻ᵀ equals numpy's inverse and pinv_psd; tril_inverse equals
    numpy's inverse."""
    n = 3
    T = n * (n + 1) // 2
    frf = synthetic_frf(random_truth(n, seed=60), rel_noise=1e-2, seed=61)
    work = jax.jit(lambda f: compress(make_problem(f, f_max_hz=40.0)))(frf)
    rng = np.random.default_rng(0)
    th = rng.standard_normal((6, T))
    diag = [i * (i + 1) // 2 + i for i in range(n)]  # L[i, i] in tril order
    th[:, diag] = np.sign(th[:, diag]) * (1.0 + np.abs(th[:, diag]))  # away from the boundary
    theta = jnp.asarray(th.ravel())
    delta = jnp.asarray(rng.standard_normal(n_params(n)))
    A = np.tril(rng.standard_normal((3, 7, 7))) + 4 * np.eye(7)

    @jax.jit
    def everything(work, theta, delta, A):
        r, D, g, F = derivatives(work, gram(work), theta)
        return dict(
            D=entry_jacobian(theta, n), Dj=jax.jacfwd(lambda t: lower_entries(t, n))(theta),
            r=r, r0=work(theta), g=g, F=F, J=jax.jacfwd(work)(theta), Jd=jvp(work, D, delta),
            inv=inverse_information(work, theta), Ainv=tril_inverse(A), pinv=pinv_psd(F),
            tr=information_trace(work, theta)[0],
        )  # fmt: skip

    out = {k: np.asarray(v) for k, v in everything(work, theta, delta, A).items()}
    for k in range(6):
        np.testing.assert_allclose(out["D"][k], out["Dj"][k][:, k * T : (k + 1) * T], atol=1e-13)
    J, r = out["J"], out["r"]
    np.testing.assert_allclose(r, out["r0"], rtol=1e-14)
    np.testing.assert_allclose(out["g"], J.T @ r, atol=1e-11 * np.abs(J.T @ r).max())
    JtJ = J.T @ J
    np.testing.assert_allclose(out["F"], JtJ, atol=1e-12 * np.abs(JtJ).max())
    np.testing.assert_allclose(out["tr"], np.trace(JtJ), rtol=1e-12)
    np.testing.assert_allclose(out["Jd"], J @ np.asarray(delta), atol=1e-11)
    ref = np.linalg.inv(JtJ)
    tol = 1e-14 * np.linalg.cond(JtJ) * np.abs(ref).max()  # both sides to ~cond·eps
    np.testing.assert_allclose(out["inv"], ref, atol=tol)
    np.testing.assert_allclose(out["inv"], out["pinv"], atol=tol)
    np.testing.assert_allclose(out["Ainv"], np.linalg.inv(A), atol=1e-13)


def test_median_nonneg_equals_nanmedian():
    """data_scale's sort-free median equals jnp.nanmedian bit for bit (odd/even counts from 1
    up, ties, masked entries, magnitudes over 10 decades)."""
    rng = np.random.default_rng(3)
    M = 701
    ours = jax.jit(median_nonneg)
    ref = jax.jit(lambda x, v: jnp.nanmedian(jnp.where(v, x, jnp.nan)))
    for count in (1, 2, 3, 4, 57, 350, 351, 701):
        x = np.abs(rng.standard_normal(M)) * 10.0 ** rng.uniform(-5, 5, M)
        x[rng.integers(0, M, M // 3)] = x[0]
        valid = np.zeros(M, bool)
        valid[rng.choice(M, count, replace=False)] = True
        assert float(ours(x, valid)) == float(ref(x, valid))
