"""gp_corr: the GP model error with correlated hand/mechanism errors, its marginal
(θ-integrated) hyperparameters, and its predictive draws (hapid.uncertainty; issue 14)."""

import numpy as np
import pytest
from helpers_fit import random_truth, synthetic_frf

from hapid.fit import fit_nls
from hapid.io import load_samples, save_samples
from hapid.uncertainty import (
    GP,
    GPCorr,
    initial_point,
    make_log_posterior,
    model_error_from,
    posterior_laplace_samples,
    predictive_plants,
)
from hapid.uncertainty._hyper import fix_gp_hyper, log_marginal_likelihood

FREQ_HZ = np.array([1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0])
H10 = np.array([np.log(0.05), np.log(0.02), np.log(0.4), np.log(0.8), 0.5, -0.3, 0.7, -0.4,
                0.6, -0.5])  # fmt: skip


@pytest.fixture(scope="module")
def case():
    truth = random_truth(2, seed=5)
    frf = synthetic_frf(truth, freq_hz=FREQ_HZ, rel_noise=1e-3, seed=6)
    nls = fit_nls(frf, weight="noise", f_max_hz=None).raise_if_failed()
    return truth, frf, nls


def _matern52_np(x, ell):
    r = np.abs(x[:, None] - x[None, :]) * np.sqrt(5.0) / ell
    return (1 + r + r**2 / 3) * np.exp(-r)


def _knee(u, c):  # asinh(ω/ω_c), u = log(ω/ω_ref), c = log(ω_c/ω_ref)
    return np.arcsinh(np.exp(u - c))


def _latent_blocks_np(h, aH, aM, u):
    """``ρ`` and the complex covariances ``K_HH, K_HM, K_MM (N, N)`` of the (f₁, f₂)-driven
    errors (E[e_H e_Mᴴ] = conj(ρ) …) for the 10 hyperparameters ``h``, magnitudes ``aH, aM``
    and ``u = log(ω/ω_ref)`` — numpy, from the documented model."""
    tau, ell, beta, kap = np.exp(h[0:2]), np.exp(h[2:4]), h[4:6], h[6:8]
    z = h[8] + 1j * h[9]
    rho = np.tanh(abs(z)) * z / abs(z)
    bH, bM = tau[0] * aH * np.exp(beta[0] * u), tau[1] * aM * np.exp(beta[1] * u)
    k1 = _matern52_np(_knee(u, kap[0]), ell[0])
    k2 = _matern52_np(_knee(u, kap[1]), ell[1])
    KHH = np.outer(bH, bH) * k1
    KHM = np.conj(rho) * np.outer(bH, bM) * k1
    KMM = np.outer(bM, bM) * (abs(rho) ** 2 * k1 + (1 - abs(rho) ** 2) * k2)
    return rho, KHH, KHM, KMM


def _element_weights_np(model, om):
    """error_scale="element" weights ``(w_H, w_M)``, each ``{(i, j): (N,)}``, from the
    documented rule (numpy, loops): ``e_ij = |K_ij| + ω|B_ij| + ω²|M_ij|`` of the reference
    model's hand or mechanism, floored at ``0.01 √(e_ii e_jj)``, divided by its RMS over the
    elements."""
    out = []
    for part in (model.hand, model.mechanism):
        M, B, K = (np.asarray(a) for a in (part.M, part.B, part.K))
        n = M.shape[0]
        raw = {(i, j): abs(K[i, j]) + om * abs(B[i, j]) + om**2 * abs(M[i, j])
               for i in range(n) for j in range(n)}  # fmt: skip
        e = {
            (i, j): np.maximum(v, 0.01 * np.sqrt(raw[i, i] * raw[j, j]))
            for (i, j), v in raw.items()
        }
        rms = np.sqrt(sum(v**2 for v in e.values()) / n**2)
        out.append({k: v / rms for k, v in e.items()})
    return out


def _reference_covariances(frf, nls, h, rho_n, element=False):
    """Per element, the real covariance of [Re r_H; Re r_T; Im r_H; Im r_T] built in numpy
    from the documented shared-latent model (e_H = τ_H b_H f₁, e_M = τ_M b_M (ρ f₁ +
    √(1−|ρ|²) f₂), f circular with Matérn-5/2 correlations in asinh(ω/ω_c)); with
    ``element`` the amplitudes of element (i, j) times :func:`_element_weights_np`."""
    zr = float(nls.scale.z_ref)
    om = np.asarray(frf.omega)
    u = np.log(om / float(nls.scale.omega_ref))
    n = frf.n
    aH = np.linalg.norm(np.asarray(frf.Z_H), axis=(1, 2)) / n / zr
    aM = np.linalg.norm(np.asarray(frf.Z_T) - np.asarray(frf.Z_H), axis=(1, 2)) / n / zr
    wH, wM = _element_weights_np(nls.model, om) if element else (None, None)
    vH = (np.asarray(frf.Z_H_std) / zr) ** 2
    vT = (np.asarray(frf.Z_T_std) / zr) ** 2
    out = {}
    for i in range(n):
        for j in range(n):
            gH, gM = (aH * wH[i, j], aM * wM[i, j]) if element else (aH, aM)
            rho, KHH, KHM, KMM = _latent_blocks_np(h, gH, gM, u)
            dH, dT = vH[:, i, j], vT[:, i, j]
            G = np.block([[KHH + np.diag(dH), KHH + KHM + np.diag(rho_n * np.sqrt(dH * dT))],
                          [(KHH + KHM).conj().T + np.diag(rho_n * np.sqrt(dH * dT)),
                           KHH + KHM + KHM.conj().T + KMM + np.diag(dT)]])  # fmt: skip
            out[i, j] = 0.5 * np.block([[G.real, -G.imag], [G.imag, G.real]])
    return out


def test_gp_corr_likelihood_matches_scipy_reference_and_reduces_to_gp(case):
    """The closed-form gp_corr likelihood equals scipy's multivariate normal density of the
    real residual vector [Re r_H; Re r_T; Im r_H; Im r_T] per element with the covariance
    built in numpy from the documented model (complex ρ couples re and im); with ρ = 0 and
    the Box–Cox coordinate its likelihood is the independent gp likelihood exactly."""
    from scipy.stats import multivariate_normal

    import hapid.uncertainty._gp as LK

    _, frf, nls = case
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                              noise_corr=0.3, model_error=GPCorr(hyper="sample"))  # fmt: skip
    assert post.names[-2:] == ["rho_re", "rho_im"] and post.n_tau == 10
    x = initial_point(post, nls)
    x[-10:] = H10
    ll = float(post.log_likelihood(x))
    m = nls.model
    s = 1j * np.asarray(frf.omega)
    zr = float(nls.scale.z_ref)
    rH = (np.asarray(frf.Z_H) - np.asarray(m.Z_H(s))) / zr
    rT = (np.asarray(frf.Z_T) - np.asarray(m.Z_T(s))) / zr
    ref = 0.0
    for (i, j), C in _reference_covariances(frf, nls, H10, 0.3).items():
        y = np.concatenate([rH[:, i, j].real, rT[:, i, j].real, rH[:, i, j].imag, rT[:, i, j].imag])
        ref += multivariate_normal(np.zeros(len(y)), C).logpdf(y)
    assert abs(ll - ref) < 1e-6 * abs(ref) + 1e-3, (ll, ref)

    # ρ = 0: the independent gp model (same kernel)
    gp = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                            noise_corr=0.3, model_error=GP(hyper="sample"))  # fmt: skip
    old = LK.GP_CORR_WARP
    try:
        LK.GP_CORR_WARP = "boxcox"
        xg = x[:-2].copy()
        x0 = x.copy()
        x0[-2:] = 0.0
        a, b = float(gp.log_likelihood(xg)), float(post.log_likelihood(x0))
    finally:
        LK.GP_CORR_WARP = old
    assert abs(a - b) < 1e-9 * abs(a), (a, b)


def test_marginal_likelihood_equals_integral_of_quadratic_form(case):
    """log p(data | h) with the matrices integrated out (closed form from the residual design)
    equals the Gaussian integral of the fixed-hyperparameter quadratic form (autodiff Hessian,
    :func:`fix_gp_hyper`) against the N(0, prior_scale²) prior, computed in numpy."""
    _, frf, nls = case
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                              model_error=GPCorr(hyper="sample"))  # fmt: skip
    lm = float(log_marginal_likelihood(post, H10))
    pf = fix_gp_hyper(post, H10)
    R, mu, ll0 = (np.asarray(a) for a in (pf.quad_R, pf.quad_mu, pf.quad_ll0))
    A, q, s2 = R.T @ R, R.shape[0], post.prior_scale**2
    b = A @ mu
    P = A + np.eye(q) / s2
    ref = (ll0 - 0.5 * mu @ A @ mu + 0.5 * b @ np.linalg.solve(P, b)
           - 0.5 * np.linalg.slogdet(P)[1] - 0.5 * q * np.log(s2))  # fmt: skip
    assert abs(lm - ref) < 1e-8 * abs(ref), (lm, ref)


@pytest.mark.slow  # a Monte Carlo check with 1500 GP-conditional draws: ~15 s CPU alone
def test_gp_corr_predictive_conditional_mean_and_file_round_trip(case, tmp_path):
    """Predictive draws of gp_corr samples: the mean of the model-error draws at a new
    frequency equals the GP conditional mean computed in numpy from the documented
    covariance (complex ρ and all), within 4 standard errors, for one θ; the samples file
    round-trips the kind."""
    truth, frf, nls = case
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                              model_error=GPCorr(hyper=tuple(H10)))  # fmt: skip
    ps = posterior_laplace_samples(post, 4, nls, key=0)
    ps = load_samples(save_samples(tmp_path / "s.npz", ps))
    assert ps.error_kind == "gp_corr" and np.allclose(ps.samples[:, -10:], H10[None])
    # every draw with the same θ: the spread is the model-error term alone
    import dataclasses

    one = dataclasses.replace(ps, samples=np.repeat(ps.samples[:1], 1500, axis=0),
                              log_prob=np.repeat(ps.log_prob[:1], 1500))  # fmt: skip
    om_new = np.array([2 * np.pi * 12.0])
    d = predictive_plants(one, om_new, max_samples=None, seed=1)
    m = one.models(np.array([0]))
    s_new = 1j * om_new
    eH = d.Z_H[:, 0] - np.asarray(m.hand(s_new))[0, 0]

    # numpy conditional mean of e_H(ω_new) given the fit residuals of θ
    zr = float(nls.scale.z_ref)
    th_model = one.models(np.array([0]))
    s = 1j * np.asarray(frf.omega)
    rH = (np.asarray(frf.Z_H) - np.asarray(th_model.hand(s))[0]) / zr
    rT = (np.asarray(frf.Z_T) - np.asarray(th_model.total(s))[0]) / zr
    om_all = np.concatenate([np.asarray(frf.omega), om_new])
    u = np.log(om_all / float(nls.scale.omega_ref))
    Nf = len(FREQ_HZ)
    a_fit_H = np.linalg.norm(np.asarray(frf.Z_H), axis=(1, 2)) / 2 / zr
    a_fit_M = np.linalg.norm(np.asarray(frf.Z_T) - np.asarray(frf.Z_H), axis=(1, 2)) / 2 / zr
    interp = lambda a: np.exp(np.interp(np.log(om_new), np.log(frf.omega), np.log(a)))  # noqa: E731
    aH = np.concatenate([a_fit_H, interp(a_fit_H)])
    aM = np.concatenate([a_fit_M, interp(a_fit_M)])
    h = H10
    rho, KHH, KHM, KMM = _latent_blocks_np(h, aH, aM, u)
    f, x = slice(0, Nf), slice(Nf, Nf + 1)
    for i, j in ((0, 0), (1, 0)):
        dH = (np.asarray(frf.Z_H_std)[:, i, j] / zr) ** 2
        dT = (np.asarray(frf.Z_T_std)[:, i, j] / zr) ** 2
        C = np.block([[KHH[f, f] + np.diag(dH), KHH[f, f] + KHM[f, f]],
                      [(KHH[f, f] + KHM[f, f]).conj().T,
                       KHH[f, f] + KHM[f, f] + KHM[f, f].conj().T + KMM[f, f] + np.diag(dT)]])  # fmt: skip
        cross = np.concatenate([KHH[x, f], KHH[x, f] + KHM[x, f]], axis=1)  # E[e_H(*) yᴴ]
        y = np.concatenate([rH[:, i, j], rT[:, i, j]])
        mean = (cross @ np.linalg.solve(C, y))[0] * zr
        sd = np.std(eH[:, i, j]) / np.sqrt(eH.shape[0])
        assert abs(np.mean(eH[:, i, j]) - mean) < 4 * sd * np.sqrt(2) + 1e-9 * abs(mean), (
            i, j, np.mean(eH[:, i, j]), mean, sd)  # fmt: skip


@pytest.mark.slow  # marginal mode search + Laplace + emcee to 50 τ + predictive draws: ~1–2 min
def test_gp_corr_predictive_calibrated_on_second_order_truth(case):
    """Strictly second-order truth (the model class is right): the gp_corr posterior's 90 %
    predictive band of P covers the truth at held-out frequencies (Laplace and emcee), and
    emcee reaches 50 τ on the quadratic-form likelihood."""
    import warnings

    from hapid.uncertainty import ShortChainWarning, band_calibration, sample_posterior

    truth, frf, nls = case
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, model_error=GPCorr(), reference=nls)
    assert post.n_tau == 0 and post.hyper_fixed.shape == (10,)  # marginal mode, held fixed
    om = 2 * np.pi * np.geomspace(1.2, 38.0, 40)
    om = om[np.min(np.abs(om[:, None] / (2 * np.pi) - FREQ_HZ[None]), axis=1) > 0.3]
    P_true = np.asarray(truth.P(1j * om))
    ps = posterior_laplace_samples(post, 300, nls, key=1)
    c = band_calibration(predictive_plants(ps, om, max_samples=300).P, P_true)
    assert c.coverage >= 0.85 and c.rel_error_median < 0.01, c
    with warnings.catch_warnings():
        warnings.simplefilter("error", ShortChainWarning)
        pe = sample_posterior(post, nls, seed=2)
    assert pe.diagnostics["converged_50tau"] and pe.error_kind == "gp_corr"
    c = band_calibration(predictive_plants(pe, om, max_samples=300).P, P_true)
    assert c.coverage >= 0.85, c


def _exact_predictive_np(frf, scale, h, om_new, prior_scale, weights_model=None,
                         marginal=False):  # fmt: skip
    """numpy reference: the exact Gaussian predictive of the true ``[Z_H; Z_T](ω_new)`` of
    the gp_corr model with fixed hyperparameters ``h``, the six matrices integrated out
    (prior N(0, prior_scale²) on their scaled entries, no PSD cone) and the GP + noise
    conditioned on the data. Returns ``(mean (E·4N*,), cov)`` in physical units over the real
    vector, per element ``[Re Z_H*, Re Z_T*, Im Z_H*, Im Z_T*]`` (:func:`_pack`'s order).
    ``weights_model``: the reference model of GPCorr(scale="element") (per-element amplitudes,
    :func:`_element_weights_np`); None = one amplitude for every element. ``marginal``:
    return instead the log density of the data with the matrices integrated out (scipy's
    dense multivariate normal), ``log p(data | h)``."""
    zr, wr = float(scale.z_ref), float(scale.omega_ref)
    n, E = frf.n, frf.n**2
    rows, cols = np.tril_indices(n)
    t = len(rows)
    om_f = np.asarray(frf.omega)
    Nf, Ns = len(om_f), len(om_new)

    def design(om):  # (N, 2, n, n, q): ∂[Z_H, Z_T]/∂v, Z = K − w²M + jwB (scaled units)
        w = om / wr
        D = np.zeros((len(om), 2, n, n, 6 * t), complex)
        for blk in range(6):
            c = (-(w**2), 1j * w, np.ones_like(w))[blk % 3]
            for k in range(t):
                S = np.zeros((n, n))
                S[rows[k], cols[k]] = S[cols[k], rows[k]] = 1.0
                D[:, 1, :, :, blk * t + k] += c[:, None, None] * S
                if blk < 3:  # hand matrices enter Z_H and Z_T
                    D[:, 0, :, :, blk * t + k] += c[:, None, None] * S
        return D

    Gf, Gs = design(om_f), design(om_new)
    aH = np.linalg.norm(np.asarray(frf.Z_H), axis=(1, 2)) / n / zr
    aM = np.linalg.norm(np.asarray(frf.Z_T) - np.asarray(frf.Z_H), axis=(1, 2)) / n / zr
    interp = lambda a: np.exp(np.interp(np.log(om_new), np.log(om_f), np.log(a)))  # noqa: E731
    om_all = np.concatenate([om_f, om_new])
    u = np.log(om_all / wr)
    aH_all, aM_all = np.r_[aH, interp(aH)], np.r_[aM, interp(aM)]
    if weights_model is not None:
        wH, wM = _element_weights_np(weights_model, om_all)

    def blocks(i, j):  # e_T = e_H + e_M
        gH, gM = (
            (aH_all * wH[i, j], aM_all * wM[i, j])
            if weights_model is not None
            else (aH_all, aM_all)
        )
        _, KHH, KHM, KMM = _latent_blocks_np(h, gH, gM, u)
        KHT = KHH + KHM
        return np.block([[KHH, KHT], [KHT.conj().T, KHT + KHM.conj().T + KMM]])

    Na = Nf + Ns
    fi = np.r_[np.arange(Nf), Na + np.arange(Nf)]
    si = np.r_[Nf + np.arange(Ns), Na + Nf + np.arange(Ns)]
    real = lambda C: 0.5 * np.block([[C.real, -C.imag], [C.imag, C.real]])  # noqa: E731  circular
    vH, vT = (np.asarray(frf.Z_H_std) / zr) ** 2, (np.asarray(frf.Z_T_std) / zr) ** 2
    ny, nt = 4 * Nf, 4 * Ns
    Cy, Cty, Ct = np.zeros((E * ny, E * ny)), np.zeros((E * nt, E * ny)), np.zeros((E * nt, E * nt))
    Jy, Jt, y = np.zeros((E * ny, 6 * t)), np.zeros((E * nt, 6 * t)), np.zeros(E * ny)
    for e in range(E):
        i, j = divmod(e, n)
        G = blocks(i, j)
        sy, st = slice(e * ny, (e + 1) * ny), slice(e * nt, (e + 1) * nt)
        Cy[sy, sy] = real(G[np.ix_(fi, fi)] + np.diag(np.r_[vH[:, i, j], vT[:, i, j]]))
        if marginal:  # the likelihood's nugget (GP_NUGGET, _JITTER of _likelihood.py)
            gH, gM = (
                (aH_all * wH[i, j], aM_all * wM[i, j])
                if weights_model is not None
                else (aH_all, aM_all)
            )
            bH, bM = gH[:Nf] * np.exp(h[4] * u[:Nf]), gM[:Nf] * np.exp(h[5] * u[:Nf])
            nug = (
                1e-8 * (np.exp(2 * h[0]) * bH**2 + np.exp(2 * h[1]) * bM**2)
                + 1e-12 * (bH + bM) ** 2
            )
            Cy[sy, sy] += 0.5 * np.diag(np.r_[nug, nug, nug, nug])
        Cty[st, sy] = real(G[np.ix_(si, fi)])
        Ct[st, st] = real(G[np.ix_(si, si)])
        gf = np.r_[Gf[:, 0, i, j], Gf[:, 1, i, j]]
        gs = np.r_[Gs[:, 0, i, j], Gs[:, 1, i, j]]
        Jy[sy], Jt[st] = np.r_[gf.real, gf.imag], np.r_[gs.real, gs.imag]
        yc = np.r_[np.asarray(frf.Z_H)[:, i, j], np.asarray(frf.Z_T)[:, i, j]] / zr
        y[sy] = np.r_[yc.real, yc.imag]
    s2 = prior_scale**2
    Cy, Cty, Ct = Cy + s2 * Jy @ Jy.T, Cty + s2 * Jt @ Jy.T, Ct + s2 * Jt @ Jt.T
    if marginal:  # log N(y; 0, Cy) (scipy's eigen-based check rejects the tiny nugget)
        Lc = np.linalg.cholesky(Cy)
        z = np.linalg.solve(Lc, y)
        return -0.5 * z @ z - np.sum(np.log(np.diag(Lc))) - 0.5 * len(y) * np.log(2 * np.pi)
    K = np.linalg.solve(Cy, Cty.T).T
    return K @ y * zr, (Ct - K @ Cty.T) * zr**2


def _pack(ZH, ZT):
    """Draws ``(S, N*, n, n)`` of Z_H, Z_T → ``(S, E·4N*)`` in :func:`_exact_predictive_np`'s
    order."""
    n = ZH.shape[-1]
    cols = []
    for e in range(n * n):
        i, j = divmod(e, n)
        c = np.concatenate([ZH[:, :, i, j], ZT[:, :, i, j]], 1)
        cols.append(np.concatenate([c.real, c.imag], 1))
    return np.concatenate(cols, 1)


@pytest.mark.slow  # 2000 Laplace draws + their GP conditionals: ~20 s CPU alone (each)
@pytest.mark.parametrize("error_scale", ["shared", "element"])
def test_gp_corr_predictive_Z_H_Z_T_equal_exact_gaussian_predictive(case, error_scale, tmp_path):
    """The predictive draws of Z_H and Z_T (Laplace θ draws + each draw's conditional GP
    model error, ``Z_T = Z_H + Z_M``) have the mean and covariance of the exact Gaussian
    predictive computed in numpy (matrices integrated out in closed form, the H–M-correlated
    GP and the noise conditioned jointly): the Z_H/Z_T bands are built from the right
    covariance, conditioned on the right residuals."""
    _, frf, nls = case
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                              model_error=GPCorr(hyper=tuple(H10), scale=error_scale))  # fmt: skip
    om_new = 2 * np.pi * np.array([1.5, 4.0, 12.0, 27.0])
    S = 2000
    ps = posterior_laplace_samples(post, S, nls, key=0)
    ps = load_samples(save_samples(tmp_path / "s.npz", ps))  # the file carries the scale
    assert ps.predictive.get("error_scale", "shared") == error_scale
    d = predictive_plants(ps, om_new, max_samples=None, seed=1)
    X = _pack(d.Z_H, d.Z_T)
    mean, cov = _exact_predictive_np(
        frf,
        nls.scale,
        H10,
        om_new,
        post.prior_scale,
        nls.model if error_scale == "element" else None,
    )
    sd = np.sqrt(np.diag(cov))
    z = (X.mean(0) - mean) / (sd / np.sqrt(S))
    assert np.max(np.abs(z)) < 4.5, np.max(np.abs(z))  # 64 means, each N(0, 1) if right
    ratio = X.var(0) / sd**2  # each ≈ 1 ± 0.03 (sd of a variance ratio from 2000 draws)
    assert 0.88 < ratio.min() and ratio.max() < 1.12, (ratio.min(), ratio.max())
    Cs = np.cov(X.T)
    corr = Cs / np.sqrt(np.outer(np.diag(Cs), np.diag(Cs)))
    assert np.max(np.abs(corr - cov / np.outer(sd, sd))) < 0.12  # H–T cross terms included


def test_gp_corr_fixed_hyper_quadratic_form_equals_full_likelihood(case):
    """gp_corr with fixed hyperparameters: the closed-form quadratic form (no autodiff Hessian)
    equals the direct likelihood (n² complex Cholesky factorizations) to 1e-10 at points far
    from its maximum, with a matrix held fixed; and the compact marginal likelihood the mode
    search uses equals the dense one."""
    import hapid.uncertainty._hyper as LK

    _, frf, nls = case
    ps = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                            noise_corr=0.3, model_error=GPCorr(hyper="sample"),
                            fixed={"K_M": np.asarray(nls.model.mechanism.K)})  # fmt: skip
    post = fix_gp_hyper(ps, H10)
    x0 = initial_point(post, nls)
    rng = np.random.default_rng(3)
    for k in (1, 2):
        x = x0 * (1 + 0.2 * k * rng.standard_normal(x0.shape))
        fast = float(post.log_likelihood(x))
        full = float(post.log_likelihood_matrices(post.model_matrices(post.full_theta(x)), H10))
        assert abs(fast - full) <= 1e-10 * abs(full), (k, fast, full)
    y0, Jc, idx = LK._compact_design(ps)
    assert Jc.shape[-1] <= 6  # element (i, j) touches entry (i, j) of the six matrices
    a = float(log_marginal_likelihood(ps, H10))
    b = float(LK._log_marginal_compact(ps, H10, y0, Jc, idx, ps.n_free))
    assert abs(a - b) <= 1e-10 * abs(a), (a, b)


def test_gp_corr_element_scale_likelihood_matches_numpy_reference(case):
    """error_scale="element": element (i, j)'s model-error amplitude is the shared one times
    e_ij / RMS e (e_ij = |K_ij| + ω|B_ij| + ω²|M_ij| of the reference model, floored at
    0.01 √(e_ii e_jj)). The weights equal the numpy rule (RMS 1 over the elements, not all
    1); the likelihood equals scipy's density with the per-element covariance built in
    numpy; the fixed-hyperparameter quadratic form (closed form, what Laplace and emcee use)
    equals the direct likelihood."""
    from scipy.stats import multivariate_normal

    _, frf, nls = case
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls, noise_corr=0.3,
                              model_error=GPCorr(hyper="sample", scale="element"))  # fmt: skip
    assert post.error.scale == "element"
    om = np.asarray(frf.omega)
    for w, ref in zip((post.w_H, post.w_M), _element_weights_np(nls.model, om), strict=True):
        w = np.asarray(w)
        assert np.allclose(np.sqrt(np.mean(w**2, axis=0)), 1.0, rtol=1e-12)
        assert np.ptp(w) > 0.1  # the elements differ
        for (i, j), r in ref.items():
            assert np.allclose(w[i * frf.n + j], r, rtol=1e-10), (i, j)
    x = initial_point(post, nls)
    x[-10:] = H10
    ll = float(post.log_likelihood(x))
    s = 1j * om
    zr = float(nls.scale.z_ref)
    rH = (np.asarray(frf.Z_H) - np.asarray(nls.model.Z_H(s))) / zr
    rT = (np.asarray(frf.Z_T) - np.asarray(nls.model.Z_T(s))) / zr
    ref = 0.0
    for (i, j), C in _reference_covariances(frf, nls, H10, 0.3, element=True).items():
        y = np.concatenate([rH[:, i, j].real, rT[:, i, j].real, rH[:, i, j].imag, rT[:, i, j].imag])
        ref += multivariate_normal(np.zeros(len(y)), C).logpdf(y)
    assert abs(ll - ref) < 1e-6 * abs(ref) + 1e-3, (ll, ref)

    pf = fix_gp_hyper(post, H10)
    x0 = initial_point(pf, nls)
    x1 = x0 * (1 + 0.3 * np.random.default_rng(4).standard_normal(x0.shape))
    fast = float(pf.log_likelihood(x1))
    full = float(pf.log_likelihood_matrices(pf.model_matrices(pf.full_theta(x1)), H10))
    assert abs(fast - full) <= 1e-10 * abs(full), (fast, full)
    with pytest.raises(ValueError, match="error_scale"):
        model_error_from("white", error_scale="element")
    with pytest.raises(ValueError, match="scale"):
        GPCorr(scale="class")


def test_gp_corr_marginal_likelihood_matches_dense_gaussian(case):
    """The marginal likelihood the hyperparameter mode search maximizes (the matrices
    integrated out in closed form, GPCorr's default ``hyper="marginal"``) equals the dense
    Gaussian density of all the data built in numpy from the documented model, and moves
    with the hyperparameters."""
    _, frf, nls = case
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                              model_error=GPCorr(hyper="sample"))  # fmt: skip
    a = float(log_marginal_likelihood(post, H10))
    ref = _exact_predictive_np(frf, nls.scale, H10, np.array([1.0]), post.prior_scale,
                               marginal=True)  # fmt: skip
    assert abs(a - ref) < 1e-8 * abs(ref), (a, ref)
    h2 = H10.copy()
    h2[0] += 1.0
    assert abs(float(log_marginal_likelihood(post, h2)) - a) > 1.0


@pytest.mark.parametrize(
    "name, value", [("GP_CORR_WARP", "boxcox"), ("GP_CORR_KERNEL", "matern32")]
)
def test_a_flipped_switch_is_another_program_not_a_stale_one(case, name, value, monkeypatch):
    """The conditional draws read the switch when their program is traced, and the program is
    cached (in this process and on disk for later ones). Flipped, flipped back and flipped
    again, each setting must give its own draws: the second flip the same as the first, the
    setting in between different (the old code returned the first traced setting's draws
    throughout, and _conditional had copied GP_CORR_KERNEL at import)."""
    import hapid.uncertainty._gp as LK

    _, frf, nls = case
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                              model_error=GPCorr(hyper=tuple(H10)))  # fmt: skip
    ps = posterior_laplace_samples(post, 8, nls, key=0)
    om = 2 * np.pi * np.array([2.5, 12.5, 27.5])
    draws = lambda: predictive_plants(ps, om, max_samples=None, seed=3).Z_H  # noqa: E731

    old = getattr(LK, name)
    monkeypatch.setattr(LK, name, value)
    z_b = draws()
    monkeypatch.setattr(LK, name, old)
    z_a = draws()
    monkeypatch.setattr(LK, name, value)
    assert np.allclose(draws(), z_b, rtol=1e-12, atol=0)
    assert np.all(np.isfinite(z_b)) and not np.allclose(z_a, z_b, rtol=1e-6)
