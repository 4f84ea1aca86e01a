"""Loop-coordinate draws (hapid.uncertainty._loopgp): the GP conditional against a dense numpy
solve, the closed-form leave-one-out against refitting without each point, the draws'
moments against the conditional, the continuations beyond the data, calibration on a truth
drawn from the GP itself, and the plants handing back Q to the tuner's scenarios."""

from math import tau as TWO_PI

import numpy as np
import pytest

from hapid.tune import make_scenarios
from hapid.uncertainty._loopgp import (
    TOP_TAPER,
    LoopGP,
    _loo,
    conditional,
    fit_loop_gp,
    loop_gp_draws,
    loop_gp_plants,
    measured_delta,
    measured_noise_var,
)
from tests.test_tune import _model


def _m52(d, ell):  # Matérn-5/2, written out independently
    r = abs(d) / ell
    return (1 + np.sqrt(5) * r + 5 * r * r / 3) * np.exp(-np.sqrt(5) * r)


def _gp(rng, K=9, n=2, ell=0.6, eta=1e-3, s2=0.7):
    u = np.log(TWO_PI * np.geomspace(1.0, 100.0, K))
    D = rng.normal(size=(K, n * n)) + 1j * rng.normal(size=(K, n * n))
    r = 0.2 + np.abs(np.sin(u))
    return LoopGP(u, D, r, ell, eta, s2, n, 0.0)


def test_conditional_matches_dense_numpy_solve():
    gp = _gp(np.random.default_rng(0))
    un = np.linspace(gp.u[0] + 0.1, gp.u[-1] - 0.1, 7)
    mean, cov = conditional(gp, un)
    a, an = gp.envelope(gp.u), gp.envelope(un)
    K = np.array([[a[i] * a[j] * (_m52(gp.u[i] - gp.u[j], gp.ell) + gp.eta * (i == j))
                   for j in range(gp.u.size)] for i in range(gp.u.size)])  # fmt: skip
    Ks = np.array([[an[i] * a[j] * _m52(un[i] - gp.u[j], gp.ell) for j in range(gp.u.size)]
                   for i in range(un.size)])  # fmt: skip
    Kss = np.array([[an[i] * an[j] * _m52(un[i] - un[j], gp.ell) for j in range(un.size)]
                    for i in range(un.size)])  # fmt: skip
    np.testing.assert_allclose(mean, Ks @ np.linalg.solve(K, gp.D), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(cov, gp.sigma2 * (Kss - Ks @ np.linalg.solve(K, Ks.T)), atol=1e-10)


def test_closed_form_loo_matches_refitting_without_each_point():
    gp = _gp(np.random.default_rng(1))
    a = gp.envelope(gp.u)
    lpd, s2 = _loo(gp.u, gp.D, a, gp.ell, gp.eta)
    z2 = []
    for k in range(gp.u.size):
        keep = np.arange(gp.u.size) != k
        R = (a[keep, None] * a[None, keep]
             * (_m52(gp.u[keep, None] - gp.u[None, keep], gp.ell) + gp.eta * np.eye(keep.sum())))  # fmt: skip
        kx = a[k] * a[keep] * _m52(gp.u[k] - gp.u[keep], gp.ell)
        mu = kx @ np.linalg.solve(R, gp.D[keep])
        v = a[k] ** 2 * (1 + gp.eta) - kx @ np.linalg.solve(R, kx)  # unit-σ² variance
        z2.append(np.abs(gp.D[k] - mu) ** 2 / v)
    s2_ref = float(np.mean(z2))
    assert s2 == pytest.approx(s2_ref, rel=1e-8)
    ref = 0.0
    for k in range(gp.u.size):  # circular complex densities with σ² = s2_ref
        keep = np.arange(gp.u.size) != k
        R = (a[keep, None] * a[None, keep]
             * (_m52(gp.u[keep, None] - gp.u[None, keep], gp.ell) + gp.eta * np.eye(keep.sum())))  # fmt: skip
        kx = a[k] * a[keep] * _m52(gp.u[k] - gp.u[keep], gp.ell)
        v = s2_ref * (a[k] ** 2 * (1 + gp.eta) - kx @ np.linalg.solve(R, kx))
        res = gp.D[k] - kx @ np.linalg.solve(R, gp.D[keep])
        ref += float(np.sum(-np.log(np.pi * v) - np.abs(res) ** 2 / v))
    assert lpd == pytest.approx(ref, rel=1e-8)


def test_draws_match_the_conditional_and_continue_as_stated():
    gp = _gp(np.random.default_rng(2))
    om = np.exp(np.concatenate([[gp.u[0] - 6.0, gp.u[0] - 1.0], np.linspace(gp.u[0] + 0.2, gp.u[-1] - 0.2, 4),
                                [gp.u[-1] + 2 * TOP_TAPER]]))  # fmt: skip
    Q = loop_gp_draws(gp, om, 20000, seed=3)
    D = Q - np.eye(2)
    mean, cov = conditional(gp, np.log(om[2:6]))
    Di = D[:, 2:6].reshape(20000, 4, 4)
    np.testing.assert_allclose(Di.mean(0), mean, atol=0.05 * np.sqrt(np.max(np.diag(cov))) + 1e-9)
    emp = np.einsum("sme,ske->mk", Di - mean, np.conj(Di - mean)).real / (20000 * 4)
    np.testing.assert_allclose(emp, cov, atol=0.05 * np.max(np.diag(cov)))
    assert np.all(Q[:, -1] == np.eye(2))  # the model's own plant above ω_e e^{2·taper}
    # below ω_1: imaginary part scaled by ω/ω_1 (→ real at DC); real part the GP's
    assert np.max(np.abs(D[:, 0].imag)) <= np.exp(-6.0) * 10 * np.max(np.abs(D[:, 1]))
    assert np.std(D[:, 0].real) > 0.1 * np.sqrt(gp.sigma2) * gp.envelope(gp.u[:1])[0]


def test_band_is_calibrated_on_a_truth_drawn_from_the_gp():
    """A smooth Δ drawn from the GP prior, 'measured' at 12 frequencies: the fitted GP's
    90 % intervals cover the held-out truth at ≈ 90 % of (frequency, element, re/im)."""
    rng = np.random.default_rng(4)
    n, ell, s = 3, 0.5, 0.3
    u_all = np.log(TWO_PI * np.geomspace(1.0, 100.0, 60))
    C = s**2 * _m52(u_all[:, None] - u_all[None], ell) + 1e-10 * np.eye(60)
    L = np.linalg.cholesky(C)
    cov, n_tot = [], 0
    model = _model(n, 0)
    meas = np.arange(60) % 5 == 0
    for rep in range(8):
        Z = (rng.normal(size=(60, n * n)) + 1j * rng.normal(size=(60, n * n))) / np.sqrt(2)
        Delta = (L @ Z).reshape(60, n, n)
        Ph = np.asarray(model.P(1j * np.exp(u_all)))
        P_true = (np.eye(n) + Delta) @ Ph
        gp = fit_loop_gp(np.exp(u_all[meas]), P_true[meas], model)
        np.testing.assert_allclose(measured_delta(np.exp(u_all[meas]), P_true[meas], model),
                                   Delta[meas], atol=1e-9)  # fmt: skip
        held = ~meas & (u_all > u_all[meas][0]) & (u_all < u_all[meas][-1])
        Qd = loop_gp_draws(gp, np.exp(u_all[held]), 400, seed=rep) - np.eye(n)
        for part in (np.real, np.imag):
            lo, hi = np.quantile(part(Qd), [0.05, 0.95], axis=0)
            t = part(Delta[held])
            cov.append(np.sum((t >= lo) & (t <= hi)))
            n_tot += t.size
    assert 0.82 <= sum(cov) / n_tot <= 0.97


def test_plants_hand_back_Q_to_the_scenarios():
    model = _model(2, 0)
    om = TWO_PI * np.array([1.0, 3.0, 10.0, 30.0, 100.0])
    rng = np.random.default_rng(5)
    Ph = np.asarray(model.P(1j * om))
    P_meas = (np.eye(2) + 0.2 * (rng.normal(size=(5, 2, 2)) + 1j * rng.normal(size=(5, 2, 2)))) @ Ph
    gp = fit_loop_gp(om, P_meas, model)
    omg = TWO_PI * np.geomspace(0.1, 300.0, 40)
    P = loop_gp_plants(gp, model, omg, 6, seed=1)
    Q = loop_gp_draws(gp, omg, 6, seed=1)
    sc = make_scenarios(P, model, omg)
    lam_ref = np.sort_complex(np.linalg.eigvals(Q).reshape(-1, 2))
    lam = np.sort_complex(np.asarray(sc.lam).reshape(-1, 2))
    np.testing.assert_allclose(lam, lam_ref, atol=1e-8)


def test_cli_loop_draws_without_frf_is_a_clean_error(tmp_path):
    from tests.helpers_cli import assert_clean_error, write_valid_files

    write_valid_files(tmp_path)
    assert_clean_error(["tune", "--model", "model.npz", "--loop-draws", "--out", "d.npz"], tmp_path,
                       "--draws loop_gp needs the measured FRF")  # fmt: skip


def test_robust_design_draws_are_objects_with_clear_errors():
    """Loop draws without an FRF, an unknown --draws name, a string where the draws object
    belongs, and neither draws nor a device: each a clear error naming the problem."""
    from hapid.tune import robust_design
    from hapid.uncertainty import LoopDraws, draws_from

    with pytest.raises(ValueError, match="loop draws need the measured FRF"):
        LoopDraws(None)
    with pytest.raises(ValueError, match="loop draws need the measured FRF"):
        draws_from("loop_gp", measured=None)
    with pytest.raises(ValueError, match="draws must be one of"):
        draws_from("gp_loop", measured=None)
    with pytest.raises(ValueError, match="parameter draws need a posterior-samples file"):
        draws_from("params")
    with pytest.raises(TypeError, match="ParamDraws or LoopDraws"):
        robust_design(_model(2, 0), "loop_gp")
    with pytest.raises(ValueError, match="draws .* a device"):
        robust_design(_model(2, 0))


def test_correlated_draws_equal_the_per_element_sum_and_have_the_covariance():
    """The loop draws' Gaussian square root as two real matrix products equals the
    per-element sum Σ_k root[m, k] z[k, s, e] over the same normal draws (numpy einsum), and
    their empirical covariance is the requested one (a clipped negative eigenvalue
    contributes nothing)."""
    from hapid.uncertainty._loopgp import _correlated, matern52

    u = np.linspace(0.0, 3.0, 40)
    cov = 2.0 * matern52((u[:, None] - u[None]) / 0.7)
    cov -= 1e-9 * np.eye(40)  # a slightly indefinite covariance: its negative part is clipped
    got = _correlated(cov, 4000, 3, np.random.default_rng(5))
    rng = np.random.default_rng(5)
    w, V = np.linalg.eigh(cov)
    keep = w > 0
    root = V[:, keep] * np.sqrt(w[keep])[None]
    r = int(keep.sum())
    z = (rng.standard_normal((r, 4000, 3)) + 1j * rng.standard_normal((r, 4000, 3))) / np.sqrt(2)
    ref = np.einsum("mk,kse->sme", root, z)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
    emp = np.einsum("sme,sne->mn", got, np.conj(got)).real / (4000 * 3)
    assert np.max(np.abs(emp - cov)) < 0.1 * np.max(cov)


def test_measured_noise_var_is_the_monte_carlo_variance_of_delta():
    """First-order propagation of the FRF's element std into Δ = Z_H Z_T⁻¹ P̂⁻¹ − I against
    numpy Monte Carlo (independent circular complex element errors of that std)."""
    rng = np.random.default_rng(11)
    n, K, S = 3, 4, 40000
    model = _model(n, 0)
    om = TWO_PI * np.array([2.0, 7.0, 20.0, 60.0])
    ZT = np.asarray(model.Z_T(1j * om)) @ (np.eye(n) + 0.1 * rng.normal(size=(K, n, n)))
    ZH = np.asarray(model.Z_H(1j * om)) @ (np.eye(n) + 0.1 * rng.normal(size=(K, n, n)))
    sH = 1e-3 * np.abs(ZH) * rng.uniform(0.5, 2.0, (K, n, n))
    sT = 1e-3 * np.abs(ZT) * rng.uniform(0.5, 2.0, (K, n, n))
    data = {"omega": om, "Z_H": ZH, "Z_T": ZT, "Z_H_std": sH, "Z_T_std": sT}
    v = measured_noise_var(data, model)

    def cn(s):  # circular complex normal with E|e|² = s²
        return (
            s * (rng.normal(size=(S, *s.shape)) + 1j * rng.normal(size=(S, *s.shape))) / np.sqrt(2)
        )

    Ph_inv = np.linalg.inv(np.asarray(model.P(1j * om)))
    D0 = ZH @ np.linalg.inv(ZT) @ Ph_inv
    Dd = (ZH + cn(sH)) @ np.linalg.inv(ZT + cn(sT)) @ Ph_inv
    mc = np.mean(np.abs(Dd - D0) ** 2, axis=(0, 2, 3))
    np.testing.assert_allclose(v, mc, rtol=0.03)


def test_conditional_and_loo_with_known_noise_match_dense_numpy():
    """With a measurement-noise variance v: the conditional is the dense solve with
    R = σ² C + diag(v), and the LOO density at the chosen σ² is the refit-without-each-point
    density (which it maximizes over the candidate σ² grid)."""
    gp0 = _gp(np.random.default_rng(12))
    v = 0.05 * np.random.default_rng(13).uniform(0.5, 2.0, gp0.u.size)
    gp = LoopGP(gp0.u, gp0.D, gp0.r, gp0.ell, gp0.eta, gp0.sigma2, gp0.n, 0.0, v)
    un = np.linspace(gp.u[0] + 0.1, gp.u[-1] - 0.1, 7)
    a, an = gp.envelope(gp.u), gp.envelope(un)
    C = np.array([[a[i] * a[j] * (_m52(gp.u[i] - gp.u[j], gp.ell) + gp.eta * (i == j))
                   for j in range(gp.u.size)] for i in range(gp.u.size)])  # fmt: skip
    Ks = gp.sigma2 * np.array([[an[i] * a[j] * _m52(un[i] - gp.u[j], gp.ell)
                                for j in range(gp.u.size)] for i in range(un.size)])  # fmt: skip
    Kss = gp.sigma2 * np.array([[an[i] * an[j] * _m52(un[i] - un[j], gp.ell)
                                 for j in range(un.size)] for i in range(un.size)])  # fmt: skip
    R = gp.sigma2 * C + np.diag(v)
    mean, cov = conditional(gp, un)
    np.testing.assert_allclose(mean, Ks @ np.linalg.solve(R, gp.D), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(cov, Kss - Ks @ np.linalg.solve(R, Ks.T), atol=1e-10)

    def lpd_refit(s2):
        out = 0.0
        Rs = s2 * C + np.diag(v)
        for k in range(gp.u.size):
            keep = np.arange(gp.u.size) != k
            kx = Rs[k, keep]
            var = Rs[k, k] - kx @ np.linalg.solve(Rs[np.ix_(keep, keep)], kx)
            res = gp.D[k] - kx @ np.linalg.solve(Rs[np.ix_(keep, keep)], gp.D[keep])
            out += float(np.sum(-np.log(np.pi * var) - np.abs(res) ** 2 / var))
        return out

    lpd, s2 = _loo(gp.u, gp.D, a, gp.ell, gp.eta, v)
    assert lpd == pytest.approx(lpd_refit(s2), rel=1e-8)
    assert lpd >= max(lpd_refit(s2 * 1.6), lpd_refit(s2 / 1.6)) - 1e-9


def test_band_covers_a_truth_measured_with_known_noise():
    """A smooth Δ from the GP prior, 'measured' at 12 frequencies with heteroscedastic noise of
    known variance v: fitted with v, the draws' 90 % intervals cover the truth (not the
    noisy data) at ≈ 90 % of (frequency, element, re/im), at and between the measured
    frequencies; fitted without v, they pass through the noisy data and cover it less."""
    rng = np.random.default_rng(14)
    n, ell, s = 2, 0.5, 0.3
    u_all = np.log(TWO_PI * np.geomspace(1.0, 100.0, 60))
    L = np.linalg.cholesky(s**2 * _m52(u_all[:, None] - u_all[None], ell) + 1e-10 * np.eye(60))
    model = _model(n, 0)
    meas = np.arange(60) % 5 == 0
    inner = (u_all >= u_all[meas][0]) & (u_all <= u_all[meas][-1])
    v = (0.05 * s) ** 2 * np.geomspace(0.3, 3.0, meas.sum())  # noise sd 1.6–5 % of the prior sd
    cover = {True: [], False: []}
    for rep in range(8):
        Z = (rng.normal(size=(60, n * n)) + 1j * rng.normal(size=(60, n * n))) / np.sqrt(2)
        Delta = (L @ Z).reshape(60, n, n)
        noise = np.sqrt(v / 2)[:, None, None] * (rng.normal(size=(meas.sum(), n, n))
                                                 + 1j * rng.normal(size=(meas.sum(), n, n)))  # fmt: skip
        Ph = np.asarray(model.P(1j * np.exp(u_all)))
        P_meas = (np.eye(n) + Delta[meas] + noise) @ Ph[meas]
        for known in (True, False):
            gp = fit_loop_gp(np.exp(u_all[meas]), P_meas, model, noise_var=v if known else None)
            Qd = loop_gp_draws(gp, np.exp(u_all[inner]), 400, seed=rep) - np.eye(n)
            for part in (np.real, np.imag):
                lo, hi = np.quantile(part(Qd), [0.05, 0.95], axis=0)
                t = part(Delta[inner])
                cover[known].append(np.mean((t >= lo) & (t <= hi)))
    assert 0.82 <= np.mean(cover[True]) <= 0.97  # measured: 0.91
    assert np.mean(cover[False]) < np.mean(cover[True]) - 0.08  # measured: 0.77
