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
from ..fit._pd import MATRIX_NAMES, Scale, n_params
from ._coords import (
    _positive_definite,
    _psd_clip,
    _unvech,
    _vech,
    _vech_jnp,
    fold_theta,
    matrix_to_theta,
)
from ._gp import (
    _JITTER,
    N_GP_CORR_HYPER,
    N_GP_HYPER,
    gp_complex_log_likelihood,
    gp_corr_covariance,
    gp_covariance,
    gp_log_likelihood,
)
from ._weights import N_CLASS_HYPER, class_weights

DEFAULT_PRIOR_SCALE = 10.0
DEFAULT_LOG_TAU_MEAN = float(np.log(0.03))
DEFAULT_LOG_TAU_SD = 2.0
TAU_NAMES = ("log_tau_H", "log_tau_M")
ELL_NAMES = ("log_ell_H", "log_ell_M")
SLOPE_NAMES = ("beta_H", "beta_M")
WARP_NAMES = ("kappa_H", "kappa_M")
DEFAULT_BETA_SD = 1.0  # prior sd of the amplitude slopes β (per e-fold of frequency)
DEFAULT_KAPPA_SD = 1.0  # prior sd of the frequency warps κ (mean 0: log-frequency)
RHO_NAMES = ("rho_re", "rho_im")  # gp_corr: unconstrained coordinates z of ρ = tanh|z| z/|z|
DEFAULT_RHO_SD = 1.0  # prior sd of each of the two ρ coordinates (mean 0: independent)
MODEL_ERRORS = ("none", "white", "gp", "gp_corr")
GP_KINDS = ("gp", "gp_corr")
DEFAULT_LOG_ELL_MEAN = float(np.log(0.5))  # length scale in natural-log frequency units
DEFAULT_LOG_ELL_SD = 1.0


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


def boundary_fixed(nls_result) -> dict:
    """``{name: matrix}`` of the NLS fit's matrices at the PSD boundary (physical units,
    projected to PSD), to pass as ``fixed`` to :func:`make_log_posterior`."""
    from ..fit._pd import project_pd

    m = project_pd(nls_result.model, floor=0.0)
    mats = dict(zip(MATRIX_NAMES, (m.hand.M, m.hand.B, m.hand.K, m.mechanism.M, m.mechanism.B,
                                   m.mechanism.K), strict=True))  # fmt: skip
    return {name: np.asarray(mats[name]) for name in nls_result.boundary}
