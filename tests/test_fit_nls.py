"""PD-constrained nonlinear fit: recovery, constraints, covariance, transforms, errors."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers_fit import PAPER_FREQ_HZ, batch_frfs, random_truth, synthetic_frf

from hapid.fit import (
    DEFAULT_SOLVER,
    FitFailedError,
    JaxoptLM,
    crhp_report,
    fit_nls,
    fit_nls_batch,
    model_relative_errors,
    n_params,
    nls_cost,
    solver_from,
)
from hapid.fit._solvers import is_default_lm
from hapid.frf import FRF, as_frf


def _psd_and_olhp(model):
    mats = [model.hand.M, model.hand.B, model.hand.K, model.mechanism.M, model.mechanism.B]
    mats += [model.mechanism.K, model.total.M, model.total.B, model.total.K]
    for A in mats:
        A = np.asarray(A)
        np.testing.assert_allclose(A, A.T, atol=1e-10 * np.abs(A).max())
        assert np.linalg.eigvalsh(A).min() >= -1e-10 * np.abs(A).max()
    for so in (model.hand, model.total):
        assert np.all(np.real(np.asarray(so.roots())) < 0)


@pytest.mark.parametrize("n", [3, pytest.param(5, marks=pytest.mark.slow), 6])  # 5: CI budget
def test_nls_recovers_truth_psd_and_stable(n):
    truth = random_truth(n, seed=30 + n)
    frf = synthetic_frf(truth, PAPER_FREQ_HZ, rel_noise=1e-4, seed=n)
    res = fit_nls(frf, f_max_hz=None)
    res.raise_if_failed()
    assert res.ok and res.status == "converged"
    assert res.theta.shape == (n_params(n),)
    err = np.asarray(model_relative_errors(res.model, truth))
    assert err.max() < 5e-3, err
    _psd_and_olhp(res.model)
    assert bool(crhp_report(res.model).ok)
    assert res.boundary == []


@pytest.mark.parametrize(
    "solver",
    ["lm", "gauss_newton", "jaxopt_lm"]
    + [pytest.param(s, marks=pytest.mark.slow) for s in ("dogleg", "bfgs", "nonlinear_cg")],
)
def test_solvers_agree(solver):
    truth = random_truth(3, seed=3)
    frf = synthetic_frf(truth, rel_noise=1e-3, seed=4)
    ref = fit_nls(frf, f_max_hz=None)
    res = fit_nls(frf, f_max_hz=None, solver=solver_from(solver), max_steps=3000)
    assert res.ok, res.summary()
    assert float(res.cost) <= float(ref.cost) * (1 + 1e-6)
    err = np.asarray(model_relative_errors(res.model, ref.model))
    assert err.max() < 1e-4, err
    _psd_and_olhp(res.model)


@pytest.mark.parametrize(
    "weight, use_P",
    [("relative", False), ("paper", False), ("noise", False), ("blend", False), ("relative", True)]
    + [pytest.param(w, True, marks=pytest.mark.slow) for w in ("paper", "noise", "blend")],
)
def test_weights_and_P_residual_recover_truth(weight, use_P):
    truth = random_truth(3, seed=8)
    frf = synthetic_frf(truth, rel_noise=1e-4, seed=9)
    res = fit_nls(frf, weight=weight, use_P_residual=use_P, f_max_hz=None)
    assert res.ok, res.summary()
    assert np.asarray(model_relative_errors(res.model, truth)).max() < 5e-3
    _psd_and_olhp(res.model)


def test_noise_weight_cost_is_chi_square():
    truth = random_truth(3, seed=2)
    frf = synthetic_frf(truth, rel_noise=1e-3, seed=3)
    res = fit_nls(frf, weight="noise", f_max_hz=None)
    dof = int(res.n_residuals) - n_params(3)
    assert int(res.n_residuals) == 2 * 2 * 9 * 28
    assert 0.8 < 2 * float(res.cost) / dof < 1.2
    assert float(res.sigma2) == 1.0


def test_fit_band_masks_high_frequencies():
    truth = random_truth(3, seed=4)
    frf = synthetic_frf(truth, rel_noise=1e-4, seed=5)
    # corrupt everything above 40 Hz: a 40 Hz band must not see it
    f = np.asarray(frf.freq_hz)
    bad = as_frf(f, np.where(f[:, None, None] > 40, 3.0, 1.0) * np.asarray(frf.Z_H), frf.Z_T)
    res = fit_nls(bad, f_max_hz=40.0)
    assert res.ok
    assert int(res.n_residuals) == 2 * 2 * 9 * int(np.sum(f <= 40))
    assert np.asarray(model_relative_errors(res.model, truth)).max() < 5e-3


@pytest.mark.slow  # CI budget (~13 s); test_uncertainty.py::test_laplace_coverage_and_mean keeps Laplace fast
def test_laplace_covariance_matches_scatter():
    truth = random_truth(3, seed=11)
    batch = batch_frfs(truth, 60, rel_noise=1e-3, seed=1000)
    res = fit_nls_batch(batch, weight="noise", f_max_hz=None)
    assert np.all(np.asarray(res.ok))
    sd = eqx.filter_vmap(lambda r: r.model_std())(res)

    def entries(m):
        a = np.stack(
            [
                np.asarray(x)
                for x in (m.hand.M, m.hand.B, m.hand.K, m.total.M, m.total.B, m.total.K)
            ],
            1,
        )
        iu = np.triu_indices(3)
        return a[..., iu[0], iu[1]]

    ratio = entries(res.model).std(0, ddof=1) / np.median(entries(sd), 0)
    assert abs(np.median(ratio) - 1) < 0.1, ratio
    assert np.all(np.abs(ratio - 1) < 0.25), ratio
    # θ-space std property is consistent with the covariance diagonal
    np.testing.assert_allclose(np.asarray(res.std[0]) ** 2, np.diag(np.asarray(res.covariance[0])))


@pytest.mark.slow  # CI budget (~12 s); test_fit_batch.py keeps batch = singles fast
def test_jit_vmap_batch_equals_singles():
    truth = random_truth(3, seed=12)
    batch = batch_frfs(truth, 5, rel_noise=1e-3, seed=50)
    fit = lambda f: fit_nls(f, f_max_hz=None)  # noqa: E731
    out = jax.jit(jax.vmap(fit))(batch)
    assert out.status.shape == (5,) and np.all(out.status == "converged")
    for k in range(5):
        one = fit(jax.tree_util.tree_map(lambda a, k=k: a[k], batch))
        np.testing.assert_allclose(
            np.asarray(out.theta[k]), np.asarray(one.theta), rtol=1e-7, atol=1e-9
        )
        np.testing.assert_allclose(float(out.cost[k]), float(one.cost), rtol=1e-8)
    also = fit_nls_batch(batch, f_max_hz=None)
    np.testing.assert_allclose(np.asarray(also.theta), np.asarray(out.theta), rtol=1e-7, atol=1e-9)


def test_grad_of_cost_matches_finite_differences():
    truth = random_truth(3, seed=13)
    frf = synthetic_frf(truth, rel_noise=1e-2, seed=14)
    res = fit_nls(frf, f_max_hz=None, max_steps=3)  # any θ will do
    theta = res.theta + 0.01
    cost = jax.jit(lambda th: nls_cost(th, frf, scale=res.scale, f_max_hz=None))
    g = np.asarray(jax.grad(cost)(theta))
    rng = np.random.default_rng(0)
    for _ in range(5):
        d = rng.standard_normal(theta.shape)
        h = 1e-6
        fd = (float(cost(theta + h * d)) - float(cost(theta - h * d))) / (2 * h)
        np.testing.assert_allclose(g @ d, fd, rtol=1e-5)
    # at the optimum the gradient vanishes
    opt = fit_nls(frf, f_max_hz=None)
    g0 = jax.grad(lambda th: nls_cost(th, frf, scale=opt.scale, f_max_hz=None))(opt.theta)
    assert float(jnp.max(jnp.abs(g0))) < 1e-6 * float(jnp.max(jnp.abs(jnp.asarray(g))))


def test_solver_names_map_to_objects_in_one_place():
    """solver_from is the edges' map; the batched fast path is the default LM at any
    tolerances, and only that."""
    assert solver_from() == DEFAULT_SOLVER
    assert is_default_lm(DEFAULT_SOLVER) and is_default_lm(solver_from("lm", rtol=1e-9))
    assert not is_default_lm(solver_from("lm", linear_solver="qr"))
    assert not is_default_lm(solver_from("dogleg")) and not is_default_lm("lm")
    jx = solver_from("jaxopt_lm", rtol=1e-9)
    assert isinstance(jx, JaxoptLM) and jx.rtol == 1e-9


def test_non_converged_fit_never_looks_successful():
    truth = random_truth(3, seed=15)
    frf = synthetic_frf(truth, rel_noise=1e-3, seed=16)
    cg = solver_from("nonlinear_cg")
    res = fit_nls(frf, f_max_hz=None, solver=cg, max_steps=2, ftol=0.0)
    assert res.status == "max_steps" and not bool(res.ok)
    with pytest.raises(FitFailedError, match="did not converge"):
        res.raise_if_failed()
    with pytest.raises(Exception, match="did not converge"):
        fit_nls(frf, f_max_hz=None, solver=cg, max_steps=2, ftol=0.0, throw=True)


def test_bad_input_errors():
    truth = random_truth(3, seed=17)
    frf = synthetic_frf(truth, rel_noise=1e-3, seed=18)
    Z_H = np.asarray(frf.Z_H).copy()
    Z_H[2, 0, 1] = np.nan
    nan_frf = FRF.__new__(FRF)  # bypass FRF's own check to test the fit's
    object.__setattr__(nan_frf, "omega", frf.omega)
    for name, val in (
        ("Z_H", jnp.asarray(Z_H)),
        ("Z_T", frf.Z_T),
        ("Z_H_std", None),
        ("Z_T_std", None),
        ("cond_L", None),
    ):
        object.__setattr__(nan_frf, name, val)
    with pytest.raises(ValueError, match="NaN or inf"):
        fit_nls(nan_frf)
    from hapid.fit import wls

    with pytest.raises(ValueError, match="NaN or inf"):
        wls(nan_frf)
    with pytest.raises(ValueError, match="at least 3"):
        fit_nls(frf, f_max_hz=2.5)
    with pytest.raises(ValueError, match="at least 3"):
        wls(frf, f_max_hz=1.5)
    no_std = as_frf(frf.freq_hz, frf.Z_H, frf.Z_T)
    with pytest.raises(ValueError, match="Z_H_std"):
        fit_nls(no_std, weight="noise")
    Z_T = np.asarray(frf.Z_T).copy()
    Z_T[4] = np.outer(Z_T[4, 0], np.ones(3))  # rank one at 5 Hz
    sing = as_frf(frf.freq_hz, frf.Z_H, Z_T)
    with pytest.raises(ValueError, match="Z_T is singular .* 5 Hz"):
        fit_nls(sing, use_P_residual=True)
    with pytest.raises(ValueError, match="solver_from"):
        fit_nls(frf, solver="lm")  # a name is the edges': solver_from maps it
    with pytest.raises(ValueError, match="solver must be one of .*'lm'"):
        solver_from("newton")
    with pytest.raises(ValueError, match="linear_solver must be one of"):
        solver_from("lm", linear_solver="lu")
    with pytest.raises(ValueError, match="weight"):
        fit_nls(frf, weight="inverse")
    with pytest.raises(ValueError, match="n = 4"):
        fit_nls(frf, init=random_truth(4, 0))
