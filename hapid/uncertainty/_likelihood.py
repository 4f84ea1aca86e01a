# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Log-posterior of the PD-parameterized impedance model given a measured FRF.

Parameters (the vector ``x`` the sampler moves, length ``d = p + n_tau``):

- ``x[:p]`` — ``theta'`` of ``hapid.fit._pd`` (``p = 6·n(n+1)/2``, six lower-triangular
  blocks ``M_H, B_H, K_H, M_M, B_M, K_M``) in the *scaled* units of a :class:`Scale`, so the
  NLS optimum ``NLSResult.theta`` (with ``NLSResult.scale``) is a valid starting point.
- ``x[p:]`` — with ``model_error=True`` (default), ``log τ_H`` and ``log τ_M``: relative
  model-error scales of the hand and mechanism impedances (``n_tau = 2``); none otherwise.

**Sign symmetry (folding).** ``L Lᵀ`` is unchanged by flipping the sign of any column of
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
independently (scaled units are O(1); the default ``prior_scale = 10`` is weak but keeps a
Cholesky diagonal of an unidentified direction from drifting off, DESIGN.md "Priors and
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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from ..fit._pd import MATRIX_NAMES, Scale, n_from_params, n_params
from ..frf import FRF

DEFAULT_F_MAX_HZ = 40.0
DEFAULT_PRIOR_SCALE = 10.0
DEFAULT_LOG_TAU_MEAN = float(np.log(0.03))
DEFAULT_LOG_TAU_SD = 2.0
TAU_NAMES = ("log_tau_H", "log_tau_M")
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


def param_names(n: int, model_error: bool = True) -> list[str]:
    """Names of the ``d`` sampled coordinates, e.g. ``"L_M_H[1,0]"``, ``"log_tau_H"``."""
    rows, cols = np.tril_indices(n)
    names = [f"L_{m}[{i},{j}]" for m in MATRIX_NAMES for i, j in zip(rows, cols, strict=True)]
    return names + (list(TAU_NAMES) if model_error else [])


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

    @property
    def n(self) -> int:
        return int(self.Z_H.shape[-1])

    @property
    def n_theta(self) -> int:
        return n_params(self.n)

    @property
    def n_tau(self) -> int:
        return 2 if self.model_error else 0

    @property
    def dim(self) -> int:
        return self.n_theta + self.n_tau

    @property
    def names(self) -> list[str]:
        return param_names(self.n, self.model_error)

    # --- pieces --------------------------------------------------------------------------
    def model_matrices(self, theta: Float[Array, " p"]) -> Float[Array, "6 n n"]:
        """The six scaled PSD matrices ``L Lᵀ`` with the folded (``|diag|``) factors."""
        n = self.n
        rows, cols = np.tril_indices(n)
        t = n * (n + 1) // 2
        vals = theta.reshape(6, t)
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
        p = self.n_theta
        mats = self.model_matrices(x[:p])
        # s = jw (w real): Z = (K − w² M) + j w B, so no complex arithmetic is needed
        w = jnp.imag(self.s)[:, None, None]
        w2 = w**2
        reH = mats[2] - w2 * mats[0] - jnp.real(self.Z_H)
        imH = w * mats[1] - jnp.imag(self.Z_H)
        reT = reH + mats[5] - w2 * mats[3] + jnp.real(self.Z_H) - jnp.real(self.Z_T)
        imT = imH + w * mats[4] + jnp.imag(self.Z_H) - jnp.imag(self.Z_T)
        c11, c12, c22 = self.covariance_terms(x[p:])
        det = c11 * c22 - c12**2
        quad = (
            c22 * (reH**2 + imH**2) - 2.0 * c12 * (reH * reT + imH * imT) + c11 * (reT**2 + imT**2)
        ) / det
        return -jnp.sum(quad) - jnp.sum(jnp.log(det)) - 2.0 * np.log(np.pi) * det.size

    def log_prior(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        p = self.n_theta
        lp = -0.5 * jnp.sum((x[:p] / self.prior_scale) ** 2) - p * np.log(
            self.prior_scale * np.sqrt(2 * np.pi)
        )
        if self.model_error:
            z = (x[p:] - self.log_tau_mean) / self.log_tau_sd
            lp = lp - 0.5 * jnp.sum(z**2) - self.n_tau * np.log(self.log_tau_sd * np.sqrt(2 * np.pi))
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

    def split(self, xs):
        """``(theta (…, p) folded, log_tau (…, n_tau))`` of sampled coordinates."""
        xs = np.asarray(xs)
        return fold_theta(xs[..., : self.n_theta]), xs[..., self.n_theta :]


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


def make_log_posterior(
    frf: FRF,
    scale: Scale | None = None,
    *,
    f_max_hz: float | None = DEFAULT_F_MAX_HZ,
    model_error: bool = True,
    noise_corr: float = 0.0,
    prior_scale: float = DEFAULT_PRIOR_SCALE,
    log_tau_mean: float = DEFAULT_LOG_TAU_MEAN,
    log_tau_sd: float = DEFAULT_LOG_TAU_SD,
) -> LogPosterior:
    """Build the :class:`LogPosterior` of ``frf`` (module docstring for the model).

    - ``scale``: the units of θ; pass ``nls_result.scale`` so the NLS θ is a starting point
      (default: ``hapid.fit.data_scale(frf, f_max_hz)``, the same as ``fit_nls`` uses).
    - ``f_max_hz``: only frequencies ``≤ f_max_hz`` enter (default 40 Hz like ``fit_nls``;
      ``None`` = all).
    - ``model_error``: add the relative model-error scales ``log τ_H, log τ_M`` (default).
      Without it the FRF's stds must be > 0 everywhere (pure measurement-noise likelihood).
    - ``noise_corr``: correlation ρ ∈ (−1, 1) of the Z_H/Z_T measurement errors per element.
    - ``prior_scale``, ``log_tau_mean``, ``log_tau_sd``: the priors.

    Raises ``ValueError`` for a missing std, non-finite data, fewer than 3 band frequencies,
    zero std without ``model_error``, or bad options.
    """
    from ..fit._nls import data_scale

    if not isinstance(frf, FRF):
        raise ValueError(f"make_log_posterior: expected an FRF, got {type(frf).__name__}")
    if frf.Z_H_std is None or frf.Z_T_std is None:
        raise ValueError(
            "make_log_posterior: the FRF has no Z_H_std/Z_T_std; the likelihood needs the noise "
            "level (estimate the FRF from ≥ 2 periods)"
        )
    if np.ndim(frf.omega) != 1:
        raise ValueError("make_log_posterior: a single (unbatched) FRF is required")
    if not (-1.0 < noise_corr < 1.0):
        raise ValueError(f"noise_corr must be in (-1, 1), got {noise_corr}")
    if not (prior_scale > 0 and log_tau_sd > 0 and np.isfinite(log_tau_mean)):
        raise ValueError("prior_scale and log_tau_sd must be > 0 and log_tau_mean finite")
    band = frf if f_max_hz is None else frf.band(0.0, f_max_hz)
    if band.omega.shape[0] < 3:
        raise ValueError(
            f"make_log_posterior: only {band.omega.shape[0]} frequencies ≤ f_max_hz={f_max_hz} Hz"
        )
    for name in ("Z_H", "Z_T", "Z_H_std", "Z_T_std"):
        a = np.asarray(getattr(band, name))
        if not np.all(np.isfinite(a)):
            raise ValueError(f"make_log_posterior: FRF {name} contains NaN or inf")
    if not model_error:
        for name in ("Z_H_std", "Z_T_std"):
            if np.any(np.asarray(getattr(band, name)) <= 0):
                raise ValueError(
                    f"make_log_posterior: FRF {name} has zero entries; a pure-noise likelihood "
                    "needs std > 0 everywhere (use model_error=True for a relative floor)"
                )
    scale = data_scale(frf, f_max_hz) if scale is None else scale
    zr = scale.z_ref
    n = frf.n
    Z_H, Z_T = band.Z_H / zr, band.Z_T / zr
    rms = lambda Z: jnp.linalg.norm(Z, axis=(-2, -1)) / n  # noqa: E731
    return LogPosterior(
        s=1j * band.omega / scale.omega_ref,
        Z_H=Z_H,
        Z_T=Z_T,
        var_H=(band.Z_H_std / zr) ** 2,
        var_T=(band.Z_T_std / zr) ** 2,
        a_H=rms(Z_H),
        a_M=rms(Z_T - Z_H),
        scale=scale,
        model_error=bool(model_error),
        noise_corr=float(noise_corr),
        prior_scale=float(prior_scale),
        log_tau_mean=float(log_tau_mean),
        log_tau_sd=float(log_tau_sd),
    )
