# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Gaussian-process model error over frequency: correlation kernels, frequency warps and the
per-element covariances of the ``gp`` and ``gp_corr`` model-error terms, with their Gaussian
log-likelihoods. Pure JAX; shapes in each docstring (``N`` frequencies, ``E = n²`` elements).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

N_GP_HYPER = 8
"""gp hyperparameters: log τ (2), log ℓ (2), β (2), κ (2) for the hand and mechanism terms."""
N_GP_CORR_HYPER = N_GP_HYPER + 2
"""gp_corr adds the two coordinates of the H–M correlation ρ."""
GP_NUGGET = 1e-8  # relative nugget on the GP kernel diagonal (conditioning only)
_JITTER = 1e-12  # relative variance floor (numerical safety only)


def matern32(x: Float[Array, " N"], y: Float[Array, " M"], ell) -> Float[Array, "N M"]:
    """Matérn-3/2 correlation ``(1 + √3 r/ℓ) e^{−√3 r/ℓ}``, ``r = |x − y|``."""
    r = jnp.abs(x[:, None] - y[None, :]) * (np.sqrt(3.0) / ell)
    return (1.0 + r) * jnp.exp(-r)


def matern52(x: Float[Array, " N"], y: Float[Array, " M"], ell) -> Float[Array, "N M"]:
    """Matérn-5/2 correlation ``(1 + √5 r/ℓ + 5r²/3ℓ²) e^{−√5 r/ℓ}``, ``r = |x − y|``."""
    r = jnp.abs(x[:, None] - y[None, :]) * (np.sqrt(5.0) / ell)
    return (1.0 + r + r**2 / 3.0) * jnp.exp(-r)


def matern72(x: Float[Array, " N"], y: Float[Array, " M"], ell) -> Float[Array, "N M"]:
    """Matérn-7/2 correlation ``(1 + √7 r/ℓ + 14r²/5ℓ² + 7√7 r³/15ℓ³) e^{−√7 r/ℓ}``."""
    r = jnp.abs(x[:, None] - y[None, :]) * (np.sqrt(7.0) / ell)
    return (1.0 + r + 0.4 * r**2 + r**3 / 15.0) * jnp.exp(-r)


def squared_exponential(x: Float[Array, " N"], y: Float[Array, " M"], ell) -> Float[Array, "N M"]:
    """Squared-exponential correlation ``exp(−(x − y)²/2ℓ²)``."""
    return jnp.exp(-0.5 * ((x[:, None] - y[None, :]) / ell) ** 2)


KERNELS = {
    "se": squared_exponential,
    "matern32": matern32,
    "matern52": matern52,
    "matern72": matern72,
}
GP_KERNEL = "matern52"
# gp_corr's kernel and frequency coordinate: chosen by the held-out calibration of the P band
# (benchmarks/calibrate_predictive.py; the candidates and their figures in docs/conventions.md).
GP_CORR_KERNEL = "matern52"


def kernel(x, y, ell):
    """The GP correlation in use (:data:`GP_KERNEL`)."""
    return KERNELS[GP_KERNEL](x, y, ell)


def corr_kernel(x, y, ell):
    """gp_corr's correlation in use (:data:`GP_CORR_KERNEL`)."""
    return KERNELS[GP_CORR_KERNEL](x, y, ell)


SWITCHES = ("GP_KERNEL", "GP_CORR_KERNEL", "GP_CORR_WARP")
"""The module's run-time switches: names of its settings that a jitted program reads
when it is traced. The GP conditionals, whose compiled programs :func:`hapid._aot.cached_jit`
stores on disk for later processes, take :func:`switches` as a static argument, so they are
keyed by it. Every other jitted program that reaches these settings (the likelihood, its
quadratic form, the marginal mode) is an ordinary ``jit``: after assigning a switch in a
process that has already run them, call :func:`hapid.clear_programs`, or they keep the old
setting (as any ``jax.jit`` keeps the globals it was traced with)."""


def switches() -> tuple[str, str, str]:
    """The values of :data:`SWITCHES` as they are now (a static argument of the cached GP
    conditionals: part of their key)."""
    return (GP_KERNEL, GP_CORR_KERNEL, GP_CORR_WARP)


def warp(u, kappa):
    """Box–Cox warp of log-frequency ``u = log(ω/ω_ref)``: ``(e^{κu} − 1)/κ`` (``u`` at
    ``κ = 0``; ``ω/ω_ref − 1`` at ``κ = 1``). The GP is stationary in the warped coordinate:
    with ``κ > 0`` the model error is smoother (in log-frequency) at low frequency than at high
    frequency."""
    small = jnp.abs(kappa) < 1e-6
    k = jnp.where(small, 1.0, kappa)
    return jnp.where(small, u + 0.5 * kappa * u**2, jnp.expm1(k * u) / k)


def split_hyper(hyper):
    """``(τ (2,), ℓ (2,), β (2,), κ (2,))`` of gp hyperparameters (6 — files written before
    the warp, κ = 0 — or :data:`N_GP_HYPER` = 8 numbers)."""
    tau, ell, beta = jnp.exp(hyper[:2]), jnp.exp(hyper[2:4]), hyper[4:6]
    kappa = hyper[6:8] if hyper.shape[-1] >= 8 else jnp.zeros(2, dtype=hyper.dtype)
    return tau, ell, beta, kappa


def gp_covariance(logw, a_H, a_M, var_H, var_T, noise_corr, hyper):
    """Per-element covariance of the stacked real residual ``[r_H; r_T]`` (``2N``) under the
    GP model error: ``(E, 2N, 2N)`` with ``E = n²`` elements (row-major), for the real part
    and (identically) for the imaginary part.

    ``logw (N,)`` log-frequency ``log(ω/ω_ref)``, ``a_H, a_M (N,)`` RMS element sizes,
    ``var_H, var_T (N, n, n)`` the FRF's ``std²``, ``hyper = (log τ_H, log τ_M, log ℓ_H,
    log ℓ_M, β_H, β_M, κ_H, κ_M)``. The amplitude of ``X ∈ {H, M}`` is
    ``τ_X (ω/ω_ref)^β_X a_X(ω)``; each of re/im carries half the complex variance (circular):
    ``K_X = ½ b_X b_Xᵀ ⊙ k(w_X; ℓ_X)`` with ``b_X`` that amplitude and ``w_X`` = :func:`warp`
    of ``logw`` by ``κ_X``; the blocks are ``[[K_H + D_H, K_H + D_HT], [K_H + D_HT,
    K_H + K_M + D_T]]``.
    """
    tau, ell, beta, kappa = split_hyper(hyper)
    a_H = a_H * jnp.exp(beta[0] * logw)
    a_M = a_M * jnp.exp(beta[1] * logw)
    wH, wM = warp(logw, kappa[0]), warp(logw, kappa[1])
    KH = 0.5 * tau[0] ** 2 * (a_H[:, None] * a_H[None, :]) * kernel(wH, wH, ell[0])
    KM = 0.5 * tau[1] ** 2 * (a_M[:, None] * a_M[None, :]) * kernel(wM, wM, ell[1])
    N = logw.shape[0]
    n2 = var_H.shape[-1] * var_H.shape[-2]
    dH = 0.5 * jnp.moveaxis(var_H.reshape(N, n2), 0, 1)  # (E, N)
    dT = 0.5 * jnp.moveaxis(var_T.reshape(N, n2), 0, 1)
    nug = GP_NUGGET * (jnp.diag(KH) + jnp.diag(KM)) + _JITTER * 0.5 * (a_H + a_M) ** 2
    top = jnp.concatenate([KH, KH], axis=1)
    bot = jnp.concatenate([KH, KH + KM], axis=1)
    return _plus_noise(jnp.concatenate([top, bot], axis=0), dH, dT, nug, noise_corr)


def _plus_noise(base, dH, dT, nug, noise_corr):
    """``base (2N, 2N)`` (the model-error covariance of ``[e_H; e_T]``) plus, per element,
    the measurement-noise variances ``dH, dT (E, N)`` and the nugget ``nug (N,)`` on the
    diagonal and the H–T noise covariance ``noise_corr·√(dH dT)`` on the off-diagonal
    blocks' diagonals: ``(E, 2N, 2N)``. ``base`` may also be per element ``(E, 2N, 2N)`` and
    ``nug`` ``(E, N)``."""
    dHT = noise_corr * jnp.sqrt(dH * dT)
    diag = jnp.concatenate([dH + nug, dT + nug], axis=1)  # (E, 2N)
    off = jax.vmap(jnp.diag)(dHT)  # (E, N, N)
    z = jnp.zeros_like(off)
    offb = jnp.concatenate([jnp.concatenate([z, off], 2), jnp.concatenate([off, z], 2)], 1)
    base = base if base.ndim == 3 else base[None]
    return base + jax.vmap(jnp.diag)(diag) + offb


GP_CORR_WARP = "asinh"


def corr_warp(u, c):
    """gp_corr's frequency coordinate: ``asinh(ω/ω_c)`` with ``u = log(ω/ω_ref)`` and
    ``c = log(ω_c/ω_ref)`` (the κ slot of the hyperparameters): linear in frequency below the
    knee ω_c (an analytic error function is a power series in ω there) and log-frequency above
    it. :data:`GP_CORR_WARP` ``"boxcox"`` uses :func:`warp` instead."""
    if GP_CORR_WARP == "boxcox":
        return warp(u, c)
    return jnp.arcsinh(jnp.exp(u - c))


def hm_correlation(hyper):
    """The complex H–M correlation ``ρ = tanh(|z|) z/|z|`` (``|ρ| < 1``) of gp_corr
    hyperparameters (``z = hyper[8] + i hyper[9]``); 0 for fewer than 10 numbers."""
    if hyper.shape[-1] < N_GP_CORR_HYPER:
        return jnp.zeros((), dtype=jnp.complex128)
    zr, zi = hyper[N_GP_HYPER], hyper[N_GP_HYPER + 1]
    r2 = zr**2 + zi**2
    r = jnp.sqrt(jnp.where(r2 > 0, r2, 1.0))
    f = jnp.where(r2 > 1e-12, jnp.tanh(r) / r, 1.0 - r2 / 3.0)  # tanh(r)/r → 1 − r²/3
    return f * (zr + 1j * zi)


def gp_corr_blocks(u, b_H, b_M, hyper):
    """Complex model-error covariances of gp_corr on log-frequencies ``u (N,)`` with
    amplitudes ``b_H, b_M (N,)`` (slopes already applied): ``(K_HH, K_HM, K_MM)``, each
    ``(N, N)``, ``K_XY = E[e_X e_Yᴴ]`` of one element's complex errors. Per-element amplitudes
    ``(E, N)`` (``error_scale="element"``) give ``(E, N, N)`` blocks.

    Shared latent (a linear model of coregionalization): ``e_H = τ_H b_H f₁``, ``e_M =
    τ_M b_M (ρ f₁ + √(1 − |ρ|²) f₂)`` with ``f₁, f₂`` independent circular complex GPs of unit
    variance and correlations ``k(w_H; ℓ_H)``, ``k(w_M; ℓ_M)`` (:func:`warp` of ``u`` by
    κ_H, κ_M; ``k`` the Matérn-5/2 of :data:`GP_CORR_KERNEL`; ``w`` = :func:`corr_warp`, the
    κ slots holding ``log(ω_c/ω_ref)`` of the knee frequency). So ``K_HH = τ_H² b_H b_Hᵀ ⊙ k₁``, ``K_HM = ρ̄ τ_H τ_M b_H b_Mᵀ ⊙ k₁``,
    ``K_MM = τ_M² b_M b_Mᵀ ⊙ (|ρ|² k₁ + (1 − |ρ|²) k₂)``; ``ρ = 0`` is the independent gp."""
    tau, ell, _, kappa = split_hyper(hyper)
    rho = hm_correlation(hyper)
    w1, w2 = corr_warp(u, kappa[0]), corr_warp(u, kappa[1])
    k1 = corr_kernel(w1, w1, ell[0])
    k2 = corr_kernel(w2, w2, ell[1])
    r2 = jnp.abs(rho) ** 2
    outer = lambda a, b: a[..., :, None] * b[..., None, :]  # noqa: E731
    KHH = tau[0] ** 2 * outer(b_H, b_H) * k1
    KHM = jnp.conj(rho) * tau[0] * tau[1] * outer(b_H, b_M) * k1
    KMM = tau[1] ** 2 * outer(b_M, b_M) * (r2 * k1 + (1.0 - r2) * k2)
    return KHH, KHM, KMM


def gp_corr_covariance(logw, a_H, a_M, var_H, var_T, noise_corr, hyper):
    """Hermitian covariance ``E[r rᴴ]`` of the complex residual ``r = [r_H; r_T]`` (``2N``)
    per element under the gp_corr model error: ``(E, 2N, 2N)`` complex.

    Same amplitudes ``b_X = τ_X (ω/ω_ref)^β_X a_X(ω)`` as :func:`gp_covariance` and the H–M
    cross-covariance of :func:`gp_corr_blocks`; ``e_T = e_H + e_M``:
    ``[[K_HH + D_H, K_HH + K_HM + D_HT], [·ᴴ, K_HH + K_HM + K_HMᴴ + K_MM + D_T]]`` with the
    measurement variances ``D`` (the FRF's ``std²``, correlation ``noise_corr``). With
    ``ρ = 0`` its real part is twice the per-re/im covariance of :func:`gp_covariance`.
    ``a_H, a_M`` are ``(N,)`` (one amplitude for every element) or ``(E, N)`` (per element:
    :func:`element_weights` times the RMS size)."""
    _, _, beta, _ = split_hyper(hyper)
    b_H = a_H * jnp.exp(beta[0] * logw)
    b_M = a_M * jnp.exp(beta[1] * logw)
    KHH, KHM, KMM = gp_corr_blocks(logw, b_H, b_M, hyper)
    N = logw.shape[0]
    n2 = var_H.shape[-1] * var_H.shape[-2]
    dH = jnp.moveaxis(var_H.reshape(N, n2), 0, 1)  # (E, N) complex variances std²
    dT = jnp.moveaxis(var_T.reshape(N, n2), 0, 1)
    dg = lambda K: jnp.real(jnp.diagonal(K, axis1=-2, axis2=-1))  # noqa: E731
    nug = GP_NUGGET * (dg(KHH) + dg(KMM)) + _JITTER * (b_H + b_M) ** 2
    KMH = jnp.swapaxes(KHM.conj(), -1, -2)
    top = jnp.concatenate([KHH, KHH + KHM], axis=-1)
    bot = jnp.concatenate([KHH + KMH, KHH + KHM + KMH + KMM], axis=-1)
    return _plus_noise(jnp.concatenate([top, bot], axis=-2), dH, dT, nug, noise_corr)


def gp_complex_log_likelihood(rH, rT, C):
    """Sum over elements of the circular complex Gaussian ``log CN([r_H; r_T]; 0, C_e) =
    −log det(π C_e) − rᴴ C_e⁻¹ r``; residuals ``(N, n, n)`` complex, ``C`` from
    :func:`gp_corr_covariance`."""
    N = rH.shape[0]
    flat = lambda r: jnp.moveaxis(r.reshape(N, -1), 0, 1)  # noqa: E731  (E, N)
    Y = jnp.concatenate([flat(rH), flat(rT)], 1)[..., None]  # (E, 2N, 1)
    L = jnp.linalg.cholesky(C)
    W = jax.scipy.linalg.solve_triangular(L, Y, lower=True)
    logdet = 2.0 * jnp.sum(jnp.log(jnp.real(jnp.diagonal(L, axis1=-2, axis2=-1))))
    return -jnp.sum(jnp.abs(W) ** 2) - logdet - 2 * N * np.log(np.pi) * C.shape[0]


def gp_log_likelihood(rH_re, rH_im, rT_re, rT_im, C):
    """Sum over elements and re/im of ``log N([r_H; r_T]; 0, C_e)``; residuals ``(N, n, n)``,
    ``C`` from :func:`gp_covariance`."""
    N = rH_re.shape[0]
    flat = lambda r: jnp.moveaxis(r.reshape(N, -1), 0, 1)  # noqa: E731  (E, N)
    Y = jnp.stack(
        [
            jnp.concatenate([flat(rH_re), flat(rT_re)], 1),
            jnp.concatenate([flat(rH_im), flat(rT_im)], 1),
        ],
        axis=-1,
    )  # fmt: skip  (E, 2N, 2)
    L = jnp.linalg.cholesky(C)
    W = jax.scipy.linalg.solve_triangular(L, Y, lower=True)
    logdet = 2.0 * jnp.sum(jnp.log(jnp.diagonal(L, axis1=-2, axis2=-1)))
    return -0.5 * jnp.sum(W**2) - logdet - 2 * N * np.log(2 * np.pi) * C.shape[0]
