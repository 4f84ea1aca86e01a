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


def param_names(n: int, model_error: bool = True, parameterization: str = "cholesky") -> list[str]:
    """Names of the ``d`` sampled coordinates, e.g. ``"L_M_H[1,0]"`` (Cholesky factor entry),
    ``"M_H[1,0]"`` (matrix entry), ``"log_tau_H"``."""
    rows, cols = np.tril_indices(n)
    pre = "L_" if parameterization == "cholesky" else ""
    names = [f"{pre}{m}[{i},{j}]" for m in MATRIX_NAMES for i, j in zip(rows, cols, strict=True)]
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
    parameterization: str = eqx.field(static=True, default="matrix")
    psd_constraint: bool = eqx.field(static=True, default=True)
    theta_fixed: Float[Array, " p"] | None = None  # full θ holding the fixed matrices' entries
    free_idx: tuple[int, ...] = eqx.field(static=True, default=())  # () = every entry is free

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
        names = param_names(self.n, self.model_error, self.parameterization)
        if not self.free_idx:
            return names
        return [names[i] for i in self.free_idx] + names[self.n_theta :]

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
        return dataclasses.replace(self, psd_constraint=False) if self.parameterization == "matrix" else self

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
        p = self.n_free
        mats = self.model_matrices(self.full_theta(x))
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
        p = self.n_free
        lp = -0.5 * jnp.sum((x[:p] / self.prior_scale) ** 2) - p * np.log(
            self.prior_scale * np.sqrt(2 * np.pi)
        )
        if self.model_error:
            z = (x[p:] - self.log_tau_mean) / self.log_tau_sd
            lp = lp - 0.5 * jnp.sum(z**2) - self.n_tau * np.log(self.log_tau_sd * np.sqrt(2 * np.pi))
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

    def split(self, xs):
        """``(theta (…, p), log_tau (…, n_tau))`` of sampled coordinates, θ the canonical
        Cholesky θ (folded; for ``"matrix"``, the Cholesky factors of the matrices, each
        matrix's eigenvalues first clipped at ``1e-12 ×`` its largest so a boundary matrix has
        a factor)."""
        xs = np.asarray(xs)
        th, tau = self.full_theta_numpy(xs), xs[..., self.n_free :]
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
    parameterization: str = "matrix",
    fixed: dict | None = None,
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
    - ``parameterization``: ``"matrix"`` (default; matrix entries on the PSD cone) or
      ``"cholesky"`` (the NLS fit's factors); module docstring.
    - ``fixed``: ``{name: (n, n) matrix in physical units}`` for matrices of
      ``M_H, B_H, K_H, M_M, B_M, K_M`` held at a value rather than sampled (the posterior
      *conditional* on them; matrix parameterization only). :func:`boundary_fixed` gives the
      NLS fit's matrices at the PSD boundary — e.g. ``K_M ≈ 0`` on a mechanism without
      stiffness, where the cone-truncated posterior of that matrix is nearly all boundary and
      makes ensemble moves crawl.

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
    if parameterization not in PARAMETERIZATIONS:
        raise ValueError(f"parameterization must be one of {PARAMETERIZATIONS}, got {parameterization!r}")
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
    theta_fixed, free_idx = None, ()
    if fixed:
        if parameterization != "matrix":
            raise ValueError("fixed matrices need parameterization='matrix'")
        unknown = set(fixed) - set(MATRIX_NAMES)
        if unknown:
            raise ValueError(f"fixed: unknown matrix names {sorted(unknown)}; use {MATRIX_NAMES}")
        t = n * (n + 1) // 2
        rows, cols = np.tril_indices(n)
        fac = [float(np.asarray(f)) for f in scale.factors()]
        th = np.zeros(n_params(n))
        for name, A in fixed.items():
            A = np.asarray(A, dtype=np.float64)
            if A.shape != (n, n) or not np.all(np.isfinite(A)):
                raise ValueError(f"fixed[{name!r}] must be a finite ({n}, {n}) matrix, got shape {A.shape}")
            k = MATRIX_NAMES.index(name)
            th[k * t : (k + 1) * t] = (0.5 * (A + A.T) * fac[k % 3])[rows, cols]
        blocks = [MATRIX_NAMES.index(nm) for nm in fixed]
        free_idx = tuple(i for i in range(n_params(n)) if i // t not in blocks)
        theta_fixed = jnp.asarray(th)
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
        parameterization=parameterization,
        theta_fixed=theta_fixed,
        free_idx=free_idx,
    )


def boundary_fixed(nls_result) -> dict:
    """``{name: matrix}`` of the NLS fit's matrices at the PSD boundary (physical units,
    projected to PSD), to pass as ``fixed`` to :func:`make_log_posterior`."""
    from ..fit._pd import project_pd

    m = project_pd(nls_result.model, floor=0.0)
    mats = dict(zip(MATRIX_NAMES, (m.hand.M, m.hand.B, m.hand.K, m.mechanism.M, m.mechanism.B,
                                   m.mechanism.K), strict=True))  # fmt: skip
    return {name: np.asarray(mats[name]) for name in nls_result.boundary}
