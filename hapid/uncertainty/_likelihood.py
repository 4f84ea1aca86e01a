# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Log-posterior of the PD-parameterized impedance model given a measured FRF.

Parameters (the vector ``x`` the sampler moves, length ``d = p + n_tau``), in one of two
parameterizations (``parameterization=``):

- ``"matrix"`` (default) — ``x[:p]`` are the lower-triangular *entries of the six symmetric
  matrices* ``M_H, B_H, K_H, M_M, B_M, K_M`` themselves (scaled units), with the prior
  restricted to the PSD cone (``−inf`` outside, tested by ``eigvalsh``). The model is linear
  in these coordinates, so for fixed τ the posterior is a Gaussian truncated to the cone: its
  Laplace approximation is well defined even when a matrix sits on the PSD boundary, and
  ensemble moves mix as on a Gaussian. This matters on real devices: on ``cu5`` the
  mechanism has no stiffness, ``K̂_M ≈ 0``, and in Cholesky coordinates the likelihood is
  *quartic* in that factor (``K = L Lᵀ``) — zero curvature at the optimum, a Laplace variance
  set by the prior alone (draws with K_M ≈ 10¹⁰ N/m) and emcee autocorrelation times of
  thousands of steps. Samples are returned as canonical Cholesky θ (:meth:`LogPosterior.split`)
  so everything downstream uses one representation.
- ``"cholesky"`` — ``x[:p]`` is ``theta'`` of ``hapid.fit._pd`` (``p = 6·n(n+1)/2``, six
  lower-triangular factor blocks) in the *scaled* units of a :class:`Scale`, as in the NLS fit.
- ``x[p:]`` — with ``model_error=True`` (default), ``log τ_H`` and ``log τ_M``: relative
  model-error scales of the hand and mechanism impedances (``n_tau = 2``); none otherwise.

**Sign symmetry (folding, ``"cholesky"`` only).** ``L Lᵀ`` is unchanged by flipping the sign of any column of
``L``, so the raw θ-posterior has ``2^(6n)`` mirror-image modes. Here the diagonal of each
factor enters as ``|θ'_jj|`` (the sampler's coordinate is *reflected* at 0): the density is
then symmetric under ``θ'_jj → −θ'_jj`` alone, it is continuous through 0 (no hard wall for
matrices at the PSD boundary), and every sample maps to the *canonical* factor with a
non-negative diagonal (:func:`fold_theta`). Each reflection has ``|Jacobian| = 1``, so the
folded density is the same function (times ``2^(6n)``): no Jacobian term is needed.

**Likelihood** (frequencies of the fit band only; scaled units ``Z/z_ref``). Per frequency
``ω_k`` and element ``(i, j)``, the complex residual pair ``r = (Ẑ_H − Z_H, Ẑ_T − Z_T)`` is
circular complex Gaussian, ``log p(r) = −2 log π − log det C − rᴴ C⁻¹ r`` with the real
2 × 2 covariance

    C = [[s_H² + v_H,             ρ s_H s_T + v_H       ],
         [ρ s_H s_T + v_H,        s_T² + v_H + v_M      ]]

- ``s_H, s_T`` — the FRF's ``Z_H_std, Z_T_std`` (contract: ``std = sqrt(E|Ẑ − Z|²)``, real
  and imaginary parts together, so each of re/im has variance ``std²/2``: exactly the
  circular complex Gaussian with variance ``std²``).
- ``ρ`` — ``noise_corr``, an optional correlation of the Z_H and Z_T measurement errors of
  the same element (default 0). The FRF contract carries no cross-covariance; see "What is
  not modelled" below.
- ``v_H = (τ_H a_H(ω))²`` and ``v_M = (τ_M a_M(ω))²`` — model error (a relative noise floor):
  ``a_H = ‖Z_H(ω)‖_F/n`` and ``a_M = ‖Z_T(ω) − Z_H(ω)‖_F/n`` are the RMS element sizes of
  the measured hand and mechanism impedances, so ``τ`` is a relative RMS element error.
  Hand model error ``e_H`` and mechanism model error ``e_M`` are independent, and the total
  is ``e_T = e_H + e_M`` (``Z_T = Z_M + Z_H``): that is where the Z_H/Z_T correlation
  ``v_H`` comes from. On a strictly second-order device the posterior of τ goes to the
  small values its prior allows and the likelihood tends to the pure-noise one.

``C`` does not depend on θ, so the normalization depends only on τ (cheap).

**Prior** (proper, on the sampled coordinates, so no Jacobian): ``θ'_i ~ N(0, prior_scale²)``
(Cholesky entries, or matrix entries truncated to the PSD cone) independently (scaled units are O(1); the default ``prior_scale = 10`` is weak but keeps a
Cholesky diagonal of an unidentified direction from drifting off, docs/conventions.md "Priors and
misspecification"), and ``log τ ~ N(log_tau_mean, log_tau_sd²)`` (default ``log 0.03``,
sd 2: τ from ~5·10⁻⁴ to ~1.6 within ±2 sd).

**What is not modelled.** (1) The FRF's ``std`` is per element; errors of different
elements and frequencies are independent here. With encoder noise the errors of ``Ẑ_H`` and
``Ẑ_T`` share ``δ𝓛`` (``δẐ = −Ẑ δ𝓛 𝓛⁻¹``), correlated *across* elements; the per-element ρ
only approximates that (on cu5's default protocol, with force noise only, ``Z_T_std`` is 0
and the noise correlation is exactly 0). (2) P is not a separate term: ``P = Z_H Z_T⁻¹`` is a
function of the same data, so adding it as an independent likelihood term would count the
information twice.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from ..defaults import FIT_BAND_HZ
from ..fit._pd import MATRIX_NAMES, Scale, n_from_params, n_params

DEFAULT_F_MAX_HZ = FIT_BAND_HZ
DEFAULT_PRIOR_SCALE = 10.0
DEFAULT_LOG_TAU_MEAN = float(np.log(0.03))
DEFAULT_LOG_TAU_SD = 2.0
TAU_NAMES = ("log_tau_H", "log_tau_M")
ELL_NAMES = ("log_ell_H", "log_ell_M")
SLOPE_NAMES = ("beta_H", "beta_M")
WARP_NAMES = ("kappa_H", "kappa_M")
DEFAULT_BETA_SD = 1.0  # prior sd of the amplitude slopes β (per e-fold of frequency)
DEFAULT_KAPPA_SD = 1.0  # prior sd of the frequency warps κ (mean 0: log-frequency)
N_GP_HYPER = 8
RHO_NAMES = ("rho_re", "rho_im")  # gp_corr: unconstrained coordinates z of ρ = tanh|z| z/|z|
DEFAULT_RHO_SD = 1.0  # prior sd of each of the two ρ coordinates (mean 0: independent)
N_GP_CORR_HYPER = N_GP_HYPER + 2
MODEL_ERRORS = ("none", "white", "gp", "gp_corr")
GP_KINDS = ("gp", "gp_corr")
DEFAULT_LOG_ELL_MEAN = float(np.log(0.5))  # length scale in natural-log frequency units
DEFAULT_LOG_ELL_SD = 1.0
GP_NUGGET = 1e-8  # relative nugget on the GP kernel diagonal (conditioning only)
_JITTER = 1e-12  # relative variance floor (numerical safety only)


def diag_positions(n: int) -> np.ndarray:
    """Indices in θ (length ``p``) of the diagonal entries of the six factors."""
    rows, cols = np.tril_indices(n)
    t = n * (n + 1) // 2
    d = np.flatnonzero(rows == cols)
    return np.concatenate([k * t + d for k in range(6)])


def fold_theta(theta: Float[Array, "... p"]) -> Float[Array, "... p"]:
    """Canonical θ of the folded parameterization: diagonal entries replaced by ``|·|``.

    Same model as :func:`LogPosterior.model_matrices` uses; works on any leading batch
    axes (numpy or jax arrays)."""
    n = n_from_params(int(np.shape(theta)[-1]))
    idx = diag_positions(n)
    if isinstance(theta, np.ndarray):
        out = theta.copy()
        out[..., idx] = np.abs(out[..., idx])
        return out
    return theta.at[..., idx].set(jnp.abs(theta[..., idx]))


def _positive_definite(A: Float[Array, "b n n"]) -> Array:
    """True iff every matrix of the batch is positive definite: all pivots of an unrolled
    Gaussian elimination (Sylvester's criterion) are > 0. Elementwise arithmetic only — about
    3× cheaper under ``vmap`` than ``eigvalsh`` at n = 5. The PSD boundary has measure zero
    for the sampler, so PD and PSD tests are the same density."""
    n = A.shape[-1]
    ok = jnp.ones(A.shape[:-2], dtype=bool)
    for _ in range(n):
        d = A[..., 0, 0]
        ok = ok & (d > 0)
        if A.shape[-1] > 1:
            safe = jnp.where(d > 0, d, 1.0)[..., None, None]
            A = A[..., 1:, 1:] - A[..., 1:, :1] * A[..., :1, 1:] / safe
    return jnp.all(ok)


def _unvech(v: np.ndarray, n: int) -> np.ndarray:
    """``(…, p)`` lower-triangular entries of six symmetric matrices → ``(…, 6, n, n)``."""
    rows, cols = np.tril_indices(n)
    t = len(rows)
    v = np.asarray(v, dtype=np.float64).reshape(v.shape[:-1] + (6, t))
    A = np.zeros(v.shape[:-1] + (n, n))
    A[..., rows, cols] = v
    A[..., cols, rows] = v
    return A


def _vech(A: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_unvech` (``(…, 6, n, n)`` → ``(…, p)``)."""
    n = A.shape[-1]
    rows, cols = np.tril_indices(n)
    return A[..., rows, cols].reshape(A.shape[:-3] + (-1,))


def _vech_jnp(A: Float[Array, "6 n n"]) -> Float[Array, " q"]:
    """The six matrices' lower-triangular entries ``(6·n(n+1)/2,)`` (jax)."""
    rows, cols = np.tril_indices(A.shape[-1])
    return A[:, rows, cols].reshape(-1)


def _psd_clip(A: np.ndarray, floor: float) -> np.ndarray:
    A = 0.5 * (A + np.swapaxes(A, -1, -2))
    lam, V = np.linalg.eigh(A)
    top = np.max(np.abs(lam), axis=-1, keepdims=True)
    lam = np.maximum(lam, np.maximum(floor * top, 1e-300))
    return (V * lam[..., None, :]) @ np.swapaxes(V, -1, -2)


def matrix_to_theta(v: np.ndarray, n: int, floor: float = 1e-12) -> np.ndarray:
    """Matrix-entry coordinates ``(…, p)`` → canonical Cholesky θ ``(…, p)`` (numpy)."""
    L = np.linalg.cholesky(_psd_clip(_unvech(v, n), floor))
    rows, cols = np.tril_indices(n)
    return L[..., rows, cols].reshape(L.shape[:-3] + (-1,))


def theta_to_matrix(theta: np.ndarray, n: int) -> np.ndarray:
    """Cholesky θ ``(…, p)`` → matrix-entry coordinates ``(…, p)`` (``L Lᵀ``, numpy)."""
    rows, cols = np.tril_indices(n)
    th = np.asarray(theta, dtype=np.float64)
    L = np.zeros(th.shape[:-1] + (6, n, n))
    L[..., rows, cols] = th.reshape(th.shape[:-1] + (6, -1))
    return _vech(L @ np.swapaxes(L, -1, -2))


PARAMETERIZATIONS = ("matrix", "cholesky")


def error_kind(model_error) -> str:
    """Normalize ``model_error`` (``True`` = ``"white"``, ``False`` = ``"none"``, or one of
    :data:`MODEL_ERRORS`)."""
    if model_error is True:
        return "white"
    if model_error is False or model_error is None:
        return "none"
    if model_error not in MODEL_ERRORS:
        raise ValueError(
            f"model_error must be one of {MODEL_ERRORS} (or a bool), got {model_error!r}"
        )
    return str(model_error)


def hyper_names(model_error) -> list[str]:
    """Names of the model-error coordinates after θ: none, ``log_tau_H, log_tau_M`` (white)
    or those plus ``log_ell_H, log_ell_M, beta_H, beta_M, kappa_H, kappa_M`` (gp), plus
    ``rho_re, rho_im`` (gp_corr)."""
    kind = error_kind(model_error)
    gp = list(ELL_NAMES) + list(SLOPE_NAMES) + list(WARP_NAMES) if kind in GP_KINDS else []
    gp += list(RHO_NAMES) if kind == "gp_corr" else []
    return [] if kind == "none" else list(TAU_NAMES) + gp


def param_names(n: int, model_error=True, parameterization: str = "cholesky") -> list[str]:
    """Names of the ``d`` sampled coordinates, e.g. ``"L_M_H[1,0]"`` (Cholesky factor entry),
    ``"M_H[1,0]"`` (matrix entry), ``"log_tau_H"``, ``"log_ell_H"``."""
    rows, cols = np.tril_indices(n)
    pre = "L_" if parameterization == "cholesky" else ""
    names = [f"{pre}{m}[{i},{j}]" for m in MATRIX_NAMES for i, j in zip(rows, cols, strict=True)]
    return names + hyper_names(model_error)


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
# gp_corr's kernel and frequency coordinate (GP_CORR_WARP) were chosen on cu5 and tripod3_d2
# (benchmarks/calibrate_predictive.py, Laplace, marginal hyperparameters; P coverage / width ratio):
# Matérn-5/2 + asinh knee 1.00 / 2.48 and 1.00 / 2.33; Matérn-7/2 + asinh 0.92 / 1.65 and
# 0.79 / 1.93; Matérn-7/2 + Box–Cox 0.89 / 2.43 and 0.85 / 3.11; Matérn-5/2 + Box–Cox 0.99 / 2.80
# and 0.92 / 3.94. hexapod6_d2 and second_order were checks only.
GP_CORR_KERNEL = "matern52"


def kernel(x, y, ell):
    """The GP correlation in use (:data:`GP_KERNEL`)."""
    return KERNELS[GP_KERNEL](x, y, ell)


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
    kern = KERNELS[GP_CORR_KERNEL]
    w1, w2 = corr_warp(u, kappa[0]), corr_warp(u, kappa[1])
    k1 = kern(w1, w1, ell[0])
    k2 = kern(w2, w2, ell[1])
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


class LogPosterior(eqx.Module):
    """Log-posterior ``log p(x | FRF)`` (module docstring), a callable pytree.

    ``post(x)`` for one ``x`` of shape ``(d,)``; ``post.log_prob(xs)`` for ``(W, d)`` →
    ``(W,)`` (jitted and vmapped; non-finite values become ``−inf``). Build it with
    :func:`make_log_posterior`.
    """

    s: Complex[Array, " N"]  # jω/ω_ref on the band
    Z_H: Complex[Array, "N n n"]  # scaled data
    Z_T: Complex[Array, "N n n"]
    var_H: Float[Array, "N n n"]  # (std/z_ref)²
    var_T: Float[Array, "N n n"]
    a_H: Float[Array, " N"]  # RMS element size of Z_H (scaled)
    a_M: Float[Array, " N"]  # of Z_T − Z_H
    scale: Scale
    model_error: bool = eqx.field(static=True)
    noise_corr: float = eqx.field(static=True)
    prior_scale: float = eqx.field(static=True)
    log_tau_mean: float = eqx.field(static=True)
    log_tau_sd: float = eqx.field(static=True)
    parameterization: str = eqx.field(static=True, default="matrix")
    psd_constraint: bool = eqx.field(static=True, default=True)
    theta_fixed: Float[Array, " p"] | None = None  # full θ holding the fixed matrices' entries
    free_idx: tuple[int, ...] = eqx.field(static=True, default=())  # () = every entry is free
    kind: str = eqx.field(static=True, default="white")  # model error: none | white | gp
    ref_theta: Float[Array, " p"] | None = None  # gp: reference θ (Cholesky) of a_H, a_M
    log_ell_mean: float = eqx.field(static=True, default=DEFAULT_LOG_ELL_MEAN)
    log_ell_sd: float = eqx.field(static=True, default=DEFAULT_LOG_ELL_SD)
    # gp with fixed hyperparameters (empirical Bayes, :func:`fix_gp_hyper`): the hyperparameters
    # and the log-likelihood as an exact quadratic form in the six matrices' entries
    hyper_fixed: Float[Array, " 8"] | None = None
    quad_R: Float[Array, "q q"] | None = None  # upper Cholesky factor of −∇² log-lik (q = 6t)
    quad_mu: Float[Array, " q"] | None = None  # its maximizer (scaled matrix entries)
    quad_ll0: Float[Array, ""] | None = None  # the log-likelihood there
    warp: bool = eqx.field(static=True, default=True)  # gp: learn κ (else κ ≡ 0)
    # gp_corr with error_scale="element": per-element weights (E, N) of a_H, a_M
    w_H: Float[Array, "E N"] | None = None
    w_M: Float[Array, "E N"] | None = None
    class_gamma: Float[Array, " 2"] | None = None  # error_scale="class": the γ held (fix_gp_hyper)
    error_scale: str = eqx.field(static=True, default="shared")  # :data:`ERROR_SCALES`

    def error_amplitudes(self, hyper=None):
        """The gp_corr amplitudes ``(a_H, a_M)``: ``(N,)`` shared, or ``(E, N)`` per element
        (scaled units). With ``error_scale="class"`` and ``hyper`` of :data:`N_CLASS_HYPER`
        numbers, the class weights of its last two (γ, :func:`class_weights`); otherwise the
        weights held (``w_H, w_M``)."""
        if self.error_scale == "class" and hyper is not None and hyper.shape[-1] >= N_CLASS_HYPER:
            wH, wM = class_weights(hyper[N_GP_CORR_HYPER:N_CLASS_HYPER], self.n)
            return self.a_H[None] * wH[:, None], self.a_M[None] * wM[:, None]
        if self.w_H is None:
            return self.a_H, self.a_M
        return self.a_H[None] * self.w_H, self.a_M[None] * self.w_M

    @property
    def n(self) -> int:
        return int(self.Z_H.shape[-1])

    @property
    def n_theta(self) -> int:
        return n_params(self.n)

    @property
    def n_tau(self) -> int:
        """Sampled model-error coordinates after θ: 0 (none, or gp with fixed
        hyperparameters), 2 (white: log τ), 8 (gp: log τ, log ℓ, β, κ), 10 (gp_corr: and ρ)."""
        if not self.model_error or self.hyper_fixed is not None:
            return 0
        return {"none": 0, "white": 2, "gp": N_GP_HYPER, "gp_corr": N_GP_CORR_HYPER}[self.kind]

    @property
    def n_free(self) -> int:
        """Sampled θ coordinates (``n_theta`` minus the entries of fixed matrices)."""
        return len(self.free_idx) if self.free_idx else self.n_theta

    @property
    def dim(self) -> int:
        return self.n_free + self.n_tau

    def full_theta(self, x: Float[Array, " d"]) -> Float[Array, " p"]:
        """The full θ (``p``) of a sampled ``x``: free coordinates scattered into the fixed."""
        if not self.free_idx:
            return x[: self.n_theta]
        return self.theta_fixed.at[np.asarray(self.free_idx)].set(x[: self.n_free])

    def full_theta_numpy(self, xs) -> np.ndarray:
        """:meth:`full_theta` for numpy ``(…, d)`` → ``(…, p)``."""
        xs = np.asarray(xs, dtype=np.float64)
        if not self.free_idx:
            return xs[..., : self.n_theta]
        out = np.broadcast_to(np.asarray(self.theta_fixed), xs.shape[:-1] + (self.n_theta,)).copy()
        out[..., np.asarray(self.free_idx)] = xs[..., : self.n_free]
        return out

    @property
    def names(self) -> list[str]:
        names = param_names(
            self.n, self.kind if self.model_error else "none", self.parameterization
        )
        hyp = names[self.n_theta : self.n_theta + self.n_tau]
        if not self.free_idx:
            return names[: self.n_theta] + hyp
        return [names[i] for i in self.free_idx] + hyp

    @property
    def fixed_names(self) -> list[str]:
        """Matrices held at fixed values (see ``fixed`` of :func:`make_log_posterior`)."""
        t = self.n * (self.n + 1) // 2
        free = set(self.free_idx) if self.free_idx else set(range(self.n_theta))
        return [m for k, m in enumerate(MATRIX_NAMES) if k * t not in free]

    def _sampled_blocks(self) -> tuple[int, ...]:
        """Which of the six matrices have sampled entries (fixed ones are not cone-checked)."""
        t = self.n * (self.n + 1) // 2
        if not self.free_idx:
            return tuple(range(6))
        return tuple(sorted({i // t for i in self.free_idx}))

    def unconstrained(self) -> LogPosterior:
        """The same density without the PSD-cone restriction (``"matrix"``): the Gaussian
        whose mode and curvature :func:`laplace_posterior` uses."""
        return (
            dataclasses.replace(self, psd_constraint=False)
            if self.parameterization == "matrix"
            else self
        )

    # --- pieces --------------------------------------------------------------------------
    def model_matrices(self, theta: Float[Array, " p"]) -> Float[Array, "6 n n"]:
        """The six scaled matrices: ``L Lᵀ`` with folded (``|diag|``) factors (Cholesky), or
        the symmetric matrices of the entries (matrix)."""
        n = self.n
        rows, cols = np.tril_indices(n)
        t = n * (n + 1) // 2
        vals = theta.reshape(6, t)
        if self.parameterization == "matrix":
            A = jnp.zeros((6, n, n), dtype=theta.dtype).at[:, rows, cols].set(vals)
            return A + jnp.swapaxes(A, -1, -2) - A * jnp.eye(n, dtype=theta.dtype)
        vals = jnp.where(jnp.asarray(rows == cols), jnp.abs(vals), vals)
        L = jnp.zeros((6, n, n), dtype=theta.dtype).at[:, rows, cols].set(vals)
        # elementwise product-sum: much faster than a batched 5×5 matmul under vmap on CPU
        return jnp.sum(L[:, :, None, :] * L[:, None, :, :], axis=-1)

    def covariance_terms(self, log_tau: Float[Array, " n_tau"]):
        """``(C11, C12, C22)``, each ``(N, n, n)``: the 2×2 covariance per element."""
        sH2, sT2 = self.var_H, self.var_T
        if self.model_error:
            tau = jnp.exp(log_tau)
            vH = ((tau[0] * self.a_H) ** 2)[:, None, None]
            vM = ((tau[1] * self.a_M) ** 2)[:, None, None]
        else:
            vH = vM = jnp.zeros(())
        jit = _JITTER * ((self.a_H + self.a_M) ** 2)[:, None, None]
        c11 = sH2 + vH + jit
        c22 = sT2 + vH + vM + jit
        c12 = self.noise_corr * jnp.sqrt(sH2 * sT2) + vH
        return c11, c12, c22

    def log_likelihood(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        mats = self.model_matrices(self.full_theta(x))
        if self.quad_R is not None:  # fixed gp hyperparameters: exact quadratic form
            v = _vech_jnp(mats)
            z = self.quad_R @ (v - self.quad_mu)
            return self.quad_ll0 - 0.5 * jnp.sum(z**2)
        hyper = self.hyper_fixed if self.hyper_fixed is not None else x[self.n_free :]
        return self.log_likelihood_matrices(mats, hyper)

    def log_likelihood_matrices(self, mats: Float[Array, "6 n n"], hyper) -> Float[Array, ""]:
        """The log-likelihood of the six scaled matrices ``mats`` and model-error coordinates
        ``hyper`` (log τ, and for gp log ℓ, β), computed directly (no quadratic form)."""
        # s = jw (w real): Z = (K − w² M) + j w B, so no complex arithmetic is needed
        w = jnp.imag(self.s)[:, None, None]
        w2 = w**2
        reH = mats[2] - w2 * mats[0] - jnp.real(self.Z_H)
        imH = w * mats[1] - jnp.imag(self.Z_H)
        reT = reH + mats[5] - w2 * mats[3] + jnp.real(self.Z_H) - jnp.real(self.Z_T)
        imT = imH + w * mats[4] + jnp.imag(self.Z_H) - jnp.imag(self.Z_T)
        if self.kind in GP_KINDS and self.model_error:
            if not self.warp and hyper.shape[-1] >= N_GP_HYPER:
                hyper = jnp.asarray(hyper).at[6:8].set(0.0)  # κ ≡ 0: log-frequency
            if self.kind == "gp_corr":
                aH, aM = self.error_amplitudes()
                C = gp_corr_covariance(jnp.log(w[:, 0, 0]), aH, aM, self.var_H, self.var_T,
                                       self.noise_corr, hyper)  # fmt: skip
                return gp_complex_log_likelihood(reH + 1j * imH, reT + 1j * imT, C)
            C = gp_covariance(jnp.log(w[:, 0, 0]), self.a_H, self.a_M, self.var_H, self.var_T,
                              self.noise_corr, hyper)  # fmt: skip
            return gp_log_likelihood(reH, imH, reT, imT, C)
        c11, c12, c22 = self.covariance_terms(hyper)
        det = c11 * c22 - c12**2
        quad = (
            c22 * (reH**2 + imH**2) - 2.0 * c12 * (reH * reT + imH * imT) + c11 * (reT**2 + imT**2)
        ) / det
        return -jnp.sum(quad) - jnp.sum(jnp.log(det)) - 2.0 * np.log(np.pi) * det.size

    def log_prior(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        p = self.n_free
        lp = -0.5 * jnp.sum((x[:p] / self.prior_scale) ** 2) - p * np.log(
            self.prior_scale * np.sqrt(2 * np.pi)
        )
        if self.n_tau > 0:
            z = (x[p : p + 2] - self.log_tau_mean) / self.log_tau_sd
            lp = lp - 0.5 * jnp.sum(z**2) - 2 * np.log(self.log_tau_sd * np.sqrt(2 * np.pi))
        if self.n_tau >= N_GP_HYPER:
            z = (x[p + 2 : p + 4] - self.log_ell_mean) / self.log_ell_sd
            lp = lp - 0.5 * jnp.sum(z**2) - 2 * np.log(self.log_ell_sd * np.sqrt(2 * np.pi))
            for lo, sd in ((4, DEFAULT_BETA_SD), (6, DEFAULT_KAPPA_SD)):
                z = x[p + lo : p + lo + 2] / sd
                lp = lp - 0.5 * jnp.sum(z**2) - 2 * np.log(sd * np.sqrt(2 * np.pi))
        if self.n_tau == N_GP_CORR_HYPER:
            z = x[p + N_GP_HYPER : p + N_GP_CORR_HYPER] / DEFAULT_RHO_SD
            lp = lp - 0.5 * jnp.sum(z**2) - 2 * np.log(DEFAULT_RHO_SD * np.sqrt(2 * np.pi))
        if self.parameterization == "matrix" and self.psd_constraint:
            mats = self.model_matrices(self.full_theta(x))[np.asarray(self._sampled_blocks())]
            lp = jnp.where(_positive_definite(mats), lp, -jnp.inf)
        return lp

    def __call__(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        v = self.log_likelihood(x) + self.log_prior(x)
        return jnp.where(jnp.isfinite(v), v, -jnp.inf)

    def log_prob(self, xs: Float[Array, "W d"]) -> Float[Array, " W"]:
        """Batched log-posterior ``(W, d) → (W,)`` (jit + vmap, one compile per shape)."""
        return _batched_log_prob(self, jnp.asarray(xs, dtype=jnp.float64))

    def log_prob_numpy(self, xs) -> np.ndarray:
        """:meth:`log_prob` as a float64 numpy array (what emcee's ``vectorize=True`` wants)."""
        return np.asarray(self.log_prob(np.asarray(xs, dtype=np.float64)))

    def hyper_mean(self) -> np.ndarray:
        """Prior means of the model-error coordinates ``(n_tau,)``."""
        if self.n_tau == 0:
            return np.zeros(0)
        extra = (
            [self.log_ell_mean] * 2 + [0.0] * (self.n_tau - 4) if self.n_tau >= N_GP_HYPER else []
        )
        return np.array([self.log_tau_mean] * 2 + extra)

    def predictive_data(self) -> dict:
        """What :func:`hapid.uncertainty.predictive_plants` needs to condition the model-error
        term on the fit residuals (numpy, physical units): ``kind``, ``omega (N,)`` rad/s,
        ``Z_H, Z_T (N, n, n)``, ``var_H, var_T (N, n, n)`` (std²), ``a_H, a_M (N,)`` and
        ``ref_theta (p,)`` (gp), ``noise_corr``."""
        zr = float(np.asarray(self.scale.z_ref))
        out = {"kind": self.kind if self.model_error else "none",
               "omega": np.asarray(jnp.imag(self.s)) * float(np.asarray(self.scale.omega_ref)),
               "Z_H": np.asarray(self.Z_H) * zr, "Z_T": np.asarray(self.Z_T) * zr,
               "var_H": np.asarray(self.var_H) * zr**2, "var_T": np.asarray(self.var_T) * zr**2,
               "a_H": np.asarray(self.a_H) * zr, "a_M": np.asarray(self.a_M) * zr,
               "noise_corr": np.float64(self.noise_corr)}  # fmt: skip
        if self.ref_theta is not None:
            out["ref_theta"] = np.asarray(self.ref_theta)
        if self.kind == "gp_corr":
            out["error_scale"] = self.error_scale
        if self.class_gamma is not None:
            out["class_gamma"] = np.asarray(self.class_gamma)
        return out

    def split(self, xs):
        """``(theta (…, p), log_tau (…, n_tau))`` of sampled coordinates, θ the canonical
        Cholesky θ (folded; for ``"matrix"``, the Cholesky factors of the matrices, each
        matrix's eigenvalues first clipped at ``1e-12 ×`` its largest so a boundary matrix has
        a factor)."""
        xs = np.asarray(xs)
        th, tau = self.full_theta_numpy(xs), xs[..., self.n_free :]
        if self.hyper_fixed is not None:  # fixed gp hyperparameters: carried by every draw
            h = np.asarray(self.hyper_fixed)
            tau = np.broadcast_to(h, xs.shape[:-1] + h.shape).copy()
        if self.kind in GP_KINDS and not self.warp and tau.shape[-1] >= N_GP_HYPER:
            tau = np.array(tau)
            tau[..., 6:8] = 0.0  # κ ≡ 0 (its coordinates only carry the prior)
        if self.parameterization == "matrix":
            return matrix_to_theta(th, self.n), tau
        return fold_theta(th), tau

    def project(self, xs, floor: float = 1e-9):
        """Walkers ``(…, d)`` moved into the support: for ``"matrix"``, each matrix's
        eigenvalues clipped at ``floor ×`` its largest |eigenvalue| (nearest PSD matrix up to
        the floor); unchanged for ``"cholesky"``."""
        xs = np.array(xs, dtype=np.float64)
        if self.parameterization != "matrix":
            return xs
        th = _vech(_psd_clip(_unvech(self.full_theta_numpy(xs), self.n), floor))
        xs[..., : self.n_free] = th[..., np.asarray(self.free_idx)] if self.free_idx else th
        return xs

    def free_part(self, theta) -> np.ndarray:
        """The sampled coordinates of a full θ ``(…, p)``."""
        theta = np.asarray(theta, dtype=np.float64)
        return theta[..., np.asarray(self.free_idx)] if self.free_idx else theta


def batched_log_prob(post: LogPosterior):
    """A jitted, vmapped ``f(xs (W, d)) -> (W,)`` numpy-in/numpy-out closure over ``post``.

    Lower per-call overhead than :meth:`LogPosterior.log_prob` (the data are compile-time
    constants and no pytree is flattened per call): what the emcee driver uses.
    """
    f = jax.jit(jax.vmap(post))
    d = post.dim

    def log_prob(xs):
        xs = np.asarray(xs, dtype=np.float64)
        if xs.ndim != 2 or xs.shape[-1] != d:
            raise ValueError(f"log_prob: expected (W, {d}) parameters, got shape {xs.shape}")
        return np.asarray(f(xs))

    return log_prob


@eqx.filter_jit
def _batched_log_prob(post: LogPosterior, xs):
    if xs.ndim != 2 or xs.shape[-1] != post.dim:
        raise ValueError(f"log_prob: expected (W, {post.dim}) parameters, got shape {xs.shape}")
    return jax.vmap(post)(xs)


def gp_amplitudes(
    omega, omega_fit, a_fit, ref_theta, scale: Scale
) -> tuple[np.ndarray, np.ndarray]:
    """``(a_H, a_M)`` (N,) N/m on any ``omega`` (rad/s): the data's RMS element sizes
    ``a_fit = (a_H, a_M)`` on the fit band ``omega_fit``, log-log interpolated inside it;
    outside, the reference model's sizes scaled to meet the data at the nearest band end."""
    omega = np.asarray(omega, dtype=np.float64)
    om_f = np.asarray(omega_fit, dtype=np.float64)
    ref_new = reference_amplitudes(ref_theta, scale, omega)
    ref_fit = reference_amplitudes(ref_theta, scale, om_f[[0, -1]])
    out = []
    for a, rn, rf in zip(a_fit, ref_new, ref_fit, strict=True):
        a = np.maximum(np.asarray(a, dtype=np.float64), 1e-300)
        rn, rf = np.maximum(np.asarray(rn), 1e-300), np.maximum(np.asarray(rf), 1e-300)
        v = np.exp(np.interp(np.log(omega), np.log(om_f), np.log(a)))
        v = np.where(omega < om_f[0], rn * a[0] / rf[0], v)
        out.append(np.where(omega > om_f[-1], rn * a[-1] / rf[1], v))
    return out[0], out[1]


def reference_amplitudes(ref_theta, scale: Scale, omega) -> tuple[np.ndarray, np.ndarray]:
    """``(a_H, a_M)`` (N,) in N/m: RMS element sizes ``‖Z(jω)‖_F / n`` of the reference
    model's hand and mechanism impedances on ``omega`` (rad/s) — the GP amplitude scale."""
    from ..fit._pd import theta_to_model

    m = theta_to_model(jnp.asarray(ref_theta), scale)
    s = 1j * jnp.asarray(omega, dtype=jnp.float64)
    n = m.n
    aH = jnp.linalg.norm(m.hand(s), axis=(-2, -1)) / n
    aM = jnp.linalg.norm(m.mechanism(s), axis=(-2, -1)) / n
    return aH, aM


ERROR_SCALES = ("shared", "element", "class")
CLASS_NAMES = ("gamma_H", "gamma_M")  # error_scale="class": log off-diagonal / diagonal amplitude
DEFAULT_GAMMA_SD = 2.0  # prior sd of each γ (mean 0: the shared scale)
N_CLASS_HYPER = N_GP_CORR_HYPER + 2
ELEMENT_FLOOR = 0.01  # element sizes floored at this × √(e_ii e_jj) (a model zero stays > 0)


def element_weights(ref_theta, scale: Scale, omega) -> tuple[np.ndarray, np.ndarray]:
    """Per-element weights ``(w_H, w_M)``, each ``(E, N)`` (``E = n²`` row-major, unitless),
    of the gp_corr model-error amplitude with ``error_scale="element"``, on ``omega`` (N,)
    rad/s: ``w_ij(ω) = e_ij(ω) / RMS_kl e_kl(ω)`` with ``e_ij = |K_ij| + ω |B_ij| + ω² |M_ij|``
    the size of element ``(i, j)`` of the reference model's hand (``w_H``) or mechanism
    (``w_M``) impedance — the sum of its three terms' magnitudes, so it has no dip where they
    cancel (a resonance) and is smooth in ω — floored at :data:`ELEMENT_FLOOR` ``× √(e_ii
    e_jj)`` so that an element the model leaves at zero keeps a (small) error. The model
    error is then *relative per element*: ``τ`` is the relative size of the misfit in every
    element, large and small. The RMS weight over the elements is 1, so the total error size
    ``τ a(ω)`` is that of ``error_scale="shared"``. Fixed by the fit: no hyperparameter."""
    from ..fit._pd import theta_to_model

    m = theta_to_model(jnp.asarray(ref_theta), scale)
    om = np.asarray(omega, dtype=np.float64)
    out = []
    for part in (m.hand, m.mechanism):
        e = sum(
            np.abs(np.asarray(A))[None] * om[:, None, None] ** k
            for k, A in enumerate((part.K, part.B, part.M))
        )  # fmt: skip  (N, n, n)
        d = np.diagonal(e, axis1=-2, axis2=-1)
        e = np.maximum(e, ELEMENT_FLOOR * np.sqrt(d[:, :, None] * d[:, None, :]))
        e = np.maximum(e, 1e-300)
        w = e / np.sqrt(np.mean(e**2, axis=(1, 2)))[:, None, None]
        out.append(w.reshape(om.shape[0], -1).T)
    return out[0], out[1]


def class_weights(gamma, n: int):
    """Per-element weights ``(w_H, w_M)``, each ``(E,)`` (``E = n²`` row-major, unitless), of
    the gp_corr model-error amplitude with ``error_scale="class"``: ``1`` on the diagonal and
    ``e^γ`` off it (``γ = (γ_H, γ_M)``, learned with the other hyperparameters at the mode of
    their marginal posterior, prior ``γ ~ N(0, DEFAULT_GAMMA_SD²)``), divided by their RMS over
    the elements — so ``τ a(ω)`` stays the RMS error size and ``γ = 0`` is the shared scale.
    Four amplitudes (diagonal and off-diagonal of the hand and of the mechanism) instead of
    two."""
    off = jnp.asarray(1.0 - np.eye(n).reshape(-1))
    out = []
    for g in (gamma[0], gamma[1]):
        w = jnp.exp(g * off)
        out.append(w / jnp.sqrt(jnp.mean(w**2)))
    return out[0], out[1]


def boundary_fixed(nls_result) -> dict:
    """``{name: matrix}`` of the NLS fit's matrices at the PSD boundary (physical units,
    projected to PSD), to pass as ``fixed`` to :func:`make_log_posterior`."""
    from ..fit._pd import project_pd

    m = project_pd(nls_result.model, floor=0.0)
    mats = dict(zip(MATRIX_NAMES, (m.hand.M, m.hand.B, m.hand.K, m.mechanism.M, m.mechanism.B,
                                   m.mechanism.K), strict=True))  # fmt: skip
    return {name: np.asarray(mats[name]) for name in nls_result.boundary}


GP_HYPER_MODES = ("map", "marginal", "sample")


def fix_gp_hyper(post: LogPosterior, hyper) -> LogPosterior:
    """The gp posterior with its hyperparameters ``hyper = (log τ_H, log τ_M, log ℓ_H,
    log ℓ_M, β_H, β_M, κ_H, κ_M)`` (κ may be left out: 0) held fixed (empirical Bayes; only θ is then sampled).

    For fixed hyperparameters the GP covariance of every element is a constant, and the model
    is linear in the six matrices' entries ``v`` (``6·n(n+1)/2`` scaled numbers), so the
    log-likelihood is *exactly* the quadratic ``ℓ(v) = ℓ(μ) − ½ ‖R (v − μ)‖²``. It is built
    once here (gradient and Hessian of :meth:`LogPosterior.log_likelihood_matrices` by
    autodiff, ``−∇²ℓ = RᵀR``, one Newton refinement of ``μ``); each evaluation is then one
    ``q × q`` triangular matrix-vector product (q = 90 at n = 5) instead of ``n²`` Cholesky
    factorizations of ``2N × 2N``. Draws carry ``hyper`` in their model-error columns."""
    if not (post.model_error and post.kind in GP_KINDS):
        raise ValueError("fix_gp_hyper: the posterior has no gp model error")
    h = jnp.asarray(hyper, dtype=jnp.float64)
    if post.error_scale == "class":  # γ → per-element weights held fixed, the rest as gp_corr
        if h.shape != (N_CLASS_HYPER,) or not bool(jnp.all(jnp.isfinite(h))):
            raise ValueError(f"fix_gp_hyper: error_scale='class' needs {N_CLASS_HYPER} finite "
                             f"hyperparameters (the last two γ_H, γ_M), got shape {h.shape}")  # fmt: skip
        g = h[N_GP_CORR_HYPER:]
        N = post.a_H.shape[0]
        wH, wM = (jnp.broadcast_to(w[:, None], (w.shape[0], N)) for w in class_weights(g, post.n))
        post = dataclasses.replace(post, w_H=wH, w_M=wM, class_gamma=g)
        h = h[:N_GP_CORR_HYPER]
    full = N_GP_CORR_HYPER if post.kind == "gp_corr" else N_GP_HYPER
    if h.shape not in ((6,), (N_GP_HYPER,), (full,)) or not bool(jnp.all(jnp.isfinite(h))):
        raise ValueError(f"fix_gp_hyper: hyper must be 6, {N_GP_HYPER} or {full} finite "
                         f"numbers, got shape {h.shape}")  # fmt: skip
    h = jnp.concatenate([h, jnp.zeros(full - h.shape[0])])
    base = dataclasses.replace(post, hyper_fixed=h, quad_R=None, quad_mu=None, quad_ll0=None)
    R, mu, ll0 = (
        _quadratic_form_corr(base, h) if post.kind == "gp_corr" else _quadratic_form(base, h)
    )
    if not (np.all(np.isfinite(np.asarray(R))) and np.isfinite(float(ll0))):
        raise ValueError("fix_gp_hyper: the likelihood's curvature is not positive definite at "
                         "these hyperparameters")  # fmt: skip
    return dataclasses.replace(base, quad_R=R, quad_mu=mu, quad_ll0=ll0)


@eqx.filter_jit
def _quadratic_form(post: LogPosterior, h):
    n = post.n
    rows, cols = np.tril_indices(n)
    t = len(rows)

    def ll(v):
        A = jnp.zeros((6, n, n), dtype=v.dtype).at[:, rows, cols].set(v.reshape(6, t))
        return post.log_likelihood_matrices(A + jnp.swapaxes(A, -1, -2) - A * jnp.eye(n), h)

    v0 = jnp.zeros(6 * t)
    negH = -jax.hessian(ll)(v0)
    negH = 0.5 * (negH + negH.T)
    Lc = jnp.linalg.cholesky(negH)
    mu = jax.scipy.linalg.cho_solve((Lc, True), jax.grad(ll)(v0))
    mu = mu + jax.scipy.linalg.cho_solve((Lc, True), jax.grad(ll)(mu))  # rounding
    return Lc.T, mu, ll(mu)


def _quadratic_form_corr(post: LogPosterior, h):
    """gp_corr's ``(R, μ, ℓ(μ))`` of :func:`fix_gp_hyper` in closed form, without autodiff:
    with ``z = L⁻¹ y₀`` and ``W = L⁻¹ J`` per element (:func:`_compact_design` over all
    ``6·n(n+1)/2`` entries, ``C = L Lᴴ``), ``ℓ(v) = c − ‖z‖² + bᵀv − ½ vᵀAv`` with
    ``A = 2 Re Σ WᴴW = RᵀR``, ``b = 2 Re Σ Wᴴz``, ``μ = A⁻¹b`` and ``c = −Σ log det(πC)``."""
    full = dataclasses.replace(post, free_idx=(), theta_fixed=None)
    y0, Jc, idx = _compact_design(full)
    return _quadratic_form_corr_jit(full, h, y0, Jc, idx, 6 * (post.n * (post.n + 1) // 2))


@eqx.filter_jit
def _quadratic_form_corr_jit(post: LogPosterior, h, y0, Jc, idx, q: int):
    w = jnp.imag(post.s)
    C = gp_corr_covariance(jnp.log(w), *post.error_amplitudes(), post.var_H, post.var_T,
                           post.noise_corr, h)  # fmt: skip
    L = jnp.linalg.cholesky(C)
    z = jax.scipy.linalg.solve_triangular(L, y0[..., None], lower=True)[..., 0]
    W = jax.scipy.linalg.solve_triangular(L, Jc, lower=True)  # (E, 2N, m)
    bw = 2.0 * jnp.real(jnp.einsum("eiq,ei->eq", jnp.conj(W), z))
    Aw = 2.0 * jnp.real(jnp.einsum("eiq,eir->eqr", jnp.conj(W), W))
    b = jnp.zeros(q + 1).at[idx].add(bw)[:q]
    A = jnp.zeros((q + 1, q + 1)).at[idx[:, :, None], idx[:, None, :]].add(Aw)[:q, :q]
    A = 0.5 * (A + A.T)
    Lc = jnp.linalg.cholesky(A)
    mu = jax.scipy.linalg.cho_solve((Lc, True), b)
    logdetC = 2.0 * jnp.sum(jnp.log(jnp.real(jnp.diagonal(L, axis1=-2, axis2=-1))))
    c = -logdetC - C.shape[0] * C.shape[-1] * np.log(np.pi)
    return Lc.T, mu, c - jnp.sum(jnp.abs(z) ** 2) + 0.5 * jnp.dot(b, mu)


def marginal_hyper(post: LogPosterior, h0, *, max_steps: int = 2000) -> tuple[np.ndarray, bool]:
    """``(hyper, converged)``: the gp hyperparameters that maximize their *marginal*
    posterior, the six matrices integrated out in closed form (type-II maximum likelihood
    with the hyperparameters' prior; ``gp_hyper="marginal"`` of :func:`make_log_posterior`).

    For fixed hyperparameters the residual ``r(v) = y₀ − J v`` is linear in the free matrix
    entries ``v`` (matrix parameterization) and Gaussian, so with the prior
    ``v ~ N(0, prior_scale² I)`` (the PSD restriction left out)

        log p(data | h) = c − ‖z‖² + ½ bᵀ P⁻¹ b − ½ log det P − (q/2) log prior_scale²,

    ``z = L⁻¹ y₀``, ``W = L⁻¹ J`` per element (``C = L Lᴴ``), ``b = 2 Re Σ Wᴴ z``,
    ``P = 2 Re Σ Wᴴ W + I/prior_scale²``, ``c = −Σ log det(π C)``. Unlike the joint mode
    (``gp_hyper="map"``), whose θ absorbs part of the misfit and whose model-error scales
    come out small, this counts the ``q`` fitted degrees of freedom (as REML does).
    BFGS (optimistix) from ``h0``."""
    if post.parameterization != "matrix" or post.kind not in GP_KINDS or post.n_tau == 0:
        raise ValueError("marginal_hyper: needs a gp posterior in the matrix parameterization "
                         "with sampled hyperparameters")  # fmt: skip
    h0 = jnp.asarray(h0, dtype=jnp.float64)
    y0, Jc, idx = _compact_design(post)
    h, ok = _marginal_mode(post, h0, y0, Jc, idx, int(post.n_free), max_steps)
    return np.asarray(h), bool(ok)


def _residual_design(post: LogPosterior):
    """``(y₀ (E, 2N), J (E, 2N, q))``: complex residuals ``[r_H; r_T]`` per element at free
    matrix entries ``v = 0`` and ``−∂r/∂v`` (exact: the model is linear in ``v``)."""
    N, n = post.Z_H.shape[0], post.n

    def resid(v):
        mats = post.model_matrices(post.full_theta(v))
        w = jnp.imag(post.s)[:, None, None]
        ZH = mats[2] - w**2 * mats[0] + 1j * w * mats[1]
        ZT = ZH + mats[5] - w**2 * mats[3] + 1j * w * mats[4]
        flat = lambda r: jnp.moveaxis(r.reshape(N, n * n), 0, 1)  # noqa: E731
        return jnp.concatenate([flat(post.Z_H - ZH), flat(post.Z_T - ZT)], 1)

    v0 = jnp.zeros(post.n_free)
    J = -jax.jacfwd(lambda v: jnp.stack([jnp.real(resid(v)), jnp.imag(resid(v))]))(v0)
    return resid(v0), J[0] + 1j * J[1]


def _compact_design(post: LogPosterior):
    """``(y₀ (E, 2N), J_c (E, 2N, m), idx (E, m))``: :func:`_residual_design` with each
    element's design restricted to the matrix entries it depends on. Element ``(i, j)`` of
    ``Z_H, Z_T`` involves only entry ``(i, j)`` of each of the six symmetric matrices, so
    ``m ≤ 6`` of the ``q = 6·n(n+1)/2`` columns are non-zero (``idx`` lists them, padded with
    ``q``: a zero column). The marginal likelihood then costs ``O(E·N·m²)`` instead of
    ``O(E·N·q²)`` per evaluation (q = 126 at n = 6)."""
    y0, J = _residual_design_jit(post)
    Jn = np.asarray(J)
    E, N2, q = Jn.shape
    nz = np.any(Jn != 0, axis=1)  # (E, q)
    m = max(int(nz.sum(axis=1).max()), 1)
    idx = np.full((E, m), q, dtype=np.int32)
    for e in range(E):
        cols = np.flatnonzero(nz[e])
        idx[e, : len(cols)] = cols
    Jp = np.concatenate([Jn, np.zeros((E, N2, 1), Jn.dtype)], axis=2)
    Jc = np.take_along_axis(Jp, idx[:, None, :].astype(np.int64), axis=2)
    return y0, jnp.asarray(Jc), jnp.asarray(idx)


_residual_design_jit = eqx.filter_jit(_residual_design)


def _whiten(post: LogPosterior, h, y0, J):
    """``(L, z, W)``: the Cholesky factor of the gp_corr covariance at hyperparameters ``h``
    and the residual ``y0`` and design ``J`` whitened by it (``L⁻¹ y0``, ``L⁻¹ J``)."""
    hf = jnp.concatenate([h[:N_GP_CORR_HYPER], jnp.zeros(max(N_GP_CORR_HYPER - h.shape[0], 0))])
    if not post.warp:
        hf = hf.at[6:8].set(0.0)
    w = jnp.imag(post.s)
    C = gp_corr_covariance(jnp.log(w), *post.error_amplitudes(h), post.var_H, post.var_T,
                           post.noise_corr, hf)  # fmt: skip
    L = jnp.linalg.cholesky(C)
    z = jax.scipy.linalg.solve_triangular(L, y0[..., None], lower=True)[..., 0]
    W = jax.scipy.linalg.solve_triangular(L, J, lower=True)
    return L, z, W


def _marginal_from(L, z, b, P, q: int, prior_scale):
    """``log p(data | h)`` from the whitened pieces: ``L`` (E, 2N, 2N) the covariance's
    Cholesky factors, ``z`` the whitened residual, ``b = 2 Re Wᴴz`` (q,) and ``P = 2 Re WᴴW``
    (q, q), the Gaussian prior of scale ``prior_scale`` on the q matrix entries added here."""
    Lp = jnp.linalg.cholesky(P + jnp.eye(q) / prior_scale**2)
    u = jax.scipy.linalg.solve_triangular(Lp, b, lower=True)
    logdetC = 2.0 * jnp.sum(jnp.log(jnp.real(jnp.diagonal(L, axis1=-2, axis2=-1))))
    logdetP = 2.0 * jnp.sum(jnp.log(jnp.diagonal(Lp)))
    c = -logdetC - L.shape[0] * L.shape[-1] * np.log(np.pi)
    return (
        c - jnp.sum(jnp.abs(z) ** 2) + 0.5 * jnp.sum(u**2) - 0.5 * logdetP - q * np.log(prior_scale)
    )


def _log_marginal_compact(post: LogPosterior, h, y0, Jc, idx, q: int):
    """:func:`log_marginal_likelihood` from the compact design of :func:`_compact_design`
    (same value; ``b`` and ``P`` assembled by scatter-adding each element's ``m × m`` block)."""
    L, z, W = _whiten(post, h, y0, Jc)  # W (E, 2N, m)
    bw = 2.0 * jnp.real(jnp.einsum("eiq,ei->eq", jnp.conj(W), z))
    Pw = 2.0 * jnp.real(jnp.einsum("eiq,eir->eqr", jnp.conj(W), W))
    b = jnp.zeros(q + 1).at[idx].add(bw)[:q]
    P = jnp.zeros((q + 1, q + 1)).at[idx[:, :, None], idx[:, None, :]].add(Pw)[:q, :q]
    return _marginal_from(L, z, b, P, q, post.prior_scale)


def log_marginal_likelihood(post: LogPosterior, h, y0=None, J=None):
    """``log p(data | h)`` of :func:`marginal_hyper` (the matrices integrated out)."""
    if y0 is None:
        y0, J = _residual_design(post)
    L, z, W = _whiten(post, h, y0, J)  # W (E, 2N, q)
    b = 2.0 * jnp.real(jnp.einsum("eiq,ei->q", jnp.conj(W), z))
    P = 2.0 * jnp.real(jnp.einsum("eiq,eir->qr", jnp.conj(W), W))
    return _marginal_from(L, z, b, P, J.shape[-1], post.prior_scale)


@eqx.filter_jit
def _marginal_mode(post: LogPosterior, h0, y0, Jc, idx, q: int, max_steps):
    import optimistix as optx

    prior = post.unconstrained()
    x_th = jnp.zeros(post.n_free)

    def neg(h, _):
        v = _log_marginal_compact(post, h, y0, Jc, idx, q) + prior.log_prior(
            jnp.concatenate([x_th, h[:N_GP_CORR_HYPER]])
        )
        if h.shape[0] > N_GP_CORR_HYPER:  # error_scale="class": γ ~ N(0, DEFAULT_GAMMA_SD²)
            v = v - 0.5 * jnp.sum((h[N_GP_CORR_HYPER:] / DEFAULT_GAMMA_SD) ** 2)
        return -jnp.where(jnp.isfinite(v), v, -1e300)

    sol = optx.minimise(neg, optx.BFGS(rtol=1e-9, atol=1e-9), h0, max_steps=max_steps, throw=False)
    return sol.value, sol.result == optx.RESULTS.successful
