# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Log-posterior of the PD-parameterized impedance model given a measured FRF.

Parameters (the vector ``x`` the sampler moves, length ``d = p + n_tau``): ``x[:p]`` are the
lower-triangular *entries of the six symmetric matrices* ``M_H, B_H, K_H, M_M, B_M, K_M``
themselves (scaled units), with the prior restricted to the PSD cone (``−inf`` outside,
tested by ``eigvalsh``); ``x[p:]`` are the model error's hyperparameters
(:mod:`~hapid.uncertainty._model_error`; none when they are fixed). The model is linear in
these coordinates, so for fixed hyperparameters the posterior is a Gaussian truncated to the
cone: its Laplace approximation is well defined even when a matrix sits on the PSD boundary
(a mechanism without stiffness, ``K̂_M ≈ 0``). Samples are returned as canonical Cholesky θ
(:meth:`LogPosterior.split`) so everything downstream uses one representation.

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

**Prior** (proper, on the sampled coordinates, so no Jacobian): the matrix entries
``x_i ~ N(0, prior_scale²)`` independently, truncated to the PSD cone (scaled units are O(1);
the default ``prior_scale = 10`` is weak, docs/conventions.md "Priors and
misspecification"); the hyperparameters' prior is the model error's
(:meth:`~hapid.uncertainty.ModelError.log_prior`).

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
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from ..fit._pd import MATRIX_NAMES, Scale, n_params, project_pd
from ._coords import _positive_definite, _psd_clip, _unvech, _vech, _vech_jnp, matrix_to_theta
from ._model_error import GPCorr, ModelError

DEFAULT_PRIOR_SCALE = 10.0


def param_names(n: int, model_error: ModelError | None = None,
                parameterization: str = "cholesky") -> list[str]:  # fmt: skip
    """Names of the ``d`` coordinates of a draw: the θ entries, e.g. ``"L_M_H[1,0]"`` (a
    Cholesky factor entry, ``parameterization="cholesky"``: the samples' θ) or ``"M_H[1,0]"``
    (a matrix entry, ``"matrix"``: the posterior's coordinates), then the hyperparameter names
    of ``model_error`` (``"log_tau_H"``, …; none for ``None``)."""
    if parameterization not in ("cholesky", "matrix"):
        raise ValueError(
            f"parameterization must be 'cholesky' or 'matrix', got {parameterization!r}"
        )
    rows, cols = np.tril_indices(n)
    pre = "L_" if parameterization == "cholesky" else ""
    names = [f"{pre}{m}[{i},{j}]" for m in MATRIX_NAMES for i, j in zip(rows, cols, strict=True)]
    return names + list(() if model_error is None else model_error.hyper_names)


class LogPosterior(eqx.Module):
    """Log-posterior ``log p(x | FRF)`` (module docstring), a callable pytree.

    ``post(x)`` for one ``x`` of shape ``(d,)``; ``post.log_prob(xs)`` for ``(W, d)`` →
    ``(W,)`` (jitted and vmapped; non-finite values become ``−inf``). Build it with
    :func:`make_log_posterior`; ``error`` is its model-error strategy.
    """

    s: Complex[Array, " N"]  # jω/ω_ref on the band
    Z_H: Complex[Array, "N n n"]  # scaled data
    Z_T: Complex[Array, "N n n"]
    var_H: Float[Array, "N n n"]  # (std/z_ref)²
    var_T: Float[Array, "N n n"]
    a_H: Float[Array, " N"]  # RMS element size of Z_H (scaled)
    a_M: Float[Array, " N"]  # of Z_T − Z_H
    scale: Scale
    error: ModelError = eqx.field(static=True)
    noise_corr: float = eqx.field(static=True)
    prior_scale: float = eqx.field(static=True)
    psd_constraint: bool = eqx.field(static=True, default=True)
    theta_fixed: Float[Array, " p"] | None = None  # full θ holding the fixed matrices' entries
    free_idx: tuple[int, ...] = eqx.field(static=True, default=())  # () = every entry is free
    ref_theta: Float[Array, " p"] | None = None  # gp: reference θ (Cholesky) of the amplitudes
    # gp with fixed hyperparameters (:func:`fix_hyperparameters`): the hyperparameters and the
    # log-likelihood as an exact quadratic form in the six matrices' entries
    hyper_fixed: Float[Array, " h"] | None = None
    quad_R: Float[Array, "q q"] | None = None  # upper Cholesky factor of −∇² log-lik (q = 6t)
    quad_mu: Float[Array, " q"] | None = None  # its maximizer (scaled matrix entries)
    quad_ll0: Float[Array, ""] | None = None  # the log-likelihood there
    # GPCorr(scale="element"): per-element weights (E, N) of a_H, a_M
    w_H: Float[Array, "E N"] | None = None
    w_M: Float[Array, "E N"] | None = None

    def error_amplitudes(self):
        """The gp_corr amplitudes ``(a_H, a_M)``: ``(N,)`` shared, or ``(E, N)`` per element
        with the weights held (``w_H, w_M``), scaled units."""
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
        """Sampled model-error coordinates after θ: the model error's count, or 0 when its
        hyperparameters are fixed."""
        return 0 if self.hyper_fixed is not None else self.error.n_hyper

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
        names = param_names(self.n, self.error, "matrix")
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
        """The same density without the PSD-cone restriction: the Gaussian whose mode and
        curvature :func:`laplace_posterior` uses."""
        return dataclasses.replace(self, psd_constraint=False)

    # --- pieces --------------------------------------------------------------------------
    def model_matrices(self, theta: Float[Array, " p"]) -> Float[Array, "6 n n"]:
        """The six scaled symmetric matrices of the entries ``theta`` ``(p,)``."""
        n = self.n
        rows, cols = np.tril_indices(n)
        t = n * (n + 1) // 2
        A = jnp.zeros((6, n, n), dtype=theta.dtype).at[:, rows, cols].set(theta.reshape(6, t))
        return A + jnp.swapaxes(A, -1, -2) - A * jnp.eye(n, dtype=theta.dtype)

    def log_likelihood(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        mats = self.model_matrices(self.full_theta(x))
        if self.quad_R is not None:  # fixed gp hyperparameters: exact quadratic form
            v = _vech_jnp(mats)
            z = self.quad_R @ (v - self.quad_mu)
            return self.quad_ll0 - 0.5 * jnp.sum(z**2)
        hyper = self.hyper_fixed if self.hyper_fixed is not None else x[self.n_free :]
        return self.log_likelihood_matrices(mats, hyper)

    def log_likelihood_matrices(self, mats: Float[Array, "6 n n"], hyper) -> Float[Array, ""]:
        """The log-likelihood of the six scaled matrices ``mats`` and model-error
        hyperparameters ``hyper``, computed directly (no quadratic form)."""
        # s = jw (w real): Z = (K − w² M) + j w B, so no complex arithmetic is needed
        w = jnp.imag(self.s)[:, None, None]
        w2 = w**2
        reH = mats[2] - w2 * mats[0] - jnp.real(self.Z_H)
        imH = w * mats[1] - jnp.imag(self.Z_H)
        reT = reH + mats[5] - w2 * mats[3] + jnp.real(self.Z_H) - jnp.real(self.Z_T)
        imT = imH + w * mats[4] + jnp.imag(self.Z_H) - jnp.imag(self.Z_T)
        return self.error.log_likelihood(self, reH, imH, reT, imT, hyper)

    def log_prior(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        p = self.n_free
        lp = -0.5 * jnp.sum((x[:p] / self.prior_scale) ** 2) - p * np.log(
            self.prior_scale * np.sqrt(2 * np.pi)
        )
        if self.n_tau > 0:
            lp = self.error.log_prior(lp, x[p:])
        if self.psd_constraint:
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
        """Prior means of the sampled model-error coordinates ``(n_tau,)``."""
        return self.error.hyper_mean() if self.n_tau else np.zeros(0)

    def predictive_data(self) -> dict:
        """What :func:`hapid.uncertainty.predictive_plants` needs to condition the model-error
        term on the fit residuals (numpy, physical units; stored in samples files): ``kind``,
        ``omega (N,)`` rad/s, ``Z_H, Z_T (N, n, n)``, ``var_H, var_T (N, n, n)`` (std²),
        ``a_H, a_M (N,)``, ``noise_corr``, and ``ref_theta (p,)`` (gp kinds) and
        ``error_scale`` (gp_corr)."""
        zr = float(np.asarray(self.scale.z_ref))
        out = {"kind": self.error.name,
               "omega": np.asarray(jnp.imag(self.s)) * float(np.asarray(self.scale.omega_ref)),
               "Z_H": np.asarray(self.Z_H) * zr, "Z_T": np.asarray(self.Z_T) * zr,
               "var_H": np.asarray(self.var_H) * zr**2, "var_T": np.asarray(self.var_T) * zr**2,
               "a_H": np.asarray(self.a_H) * zr, "a_M": np.asarray(self.a_M) * zr,
               "noise_corr": np.float64(self.noise_corr)}  # fmt: skip
        if self.ref_theta is not None:
            out["ref_theta"] = np.asarray(self.ref_theta)
        if isinstance(self.error, GPCorr):
            out["error_scale"] = self.error.scale
        return out

    def split(self, xs):
        """``(theta (…, p), hyper (…, n_hyper))`` of sampled coordinates: θ the canonical
        Cholesky θ of the matrices (each matrix's eigenvalues first clipped at ``1e-12 ×`` its
        largest so a boundary matrix has a factor), and the model error's hyperparameters
        (the fixed ones carried by every draw)."""
        xs = np.asarray(xs)
        th, tau = self.full_theta_numpy(xs), xs[..., self.n_free :]
        if self.hyper_fixed is not None:
            h = np.asarray(self.hyper_fixed)
            tau = np.broadcast_to(h, xs.shape[:-1] + h.shape).copy()
        return matrix_to_theta(th, self.n), tau

    def project(self, xs, floor: float = 1e-9):
        """Walkers ``(…, d)`` moved into the support: each matrix's eigenvalues clipped at
        ``floor ×`` its largest |eigenvalue| (nearest PSD matrix up to the floor)."""
        xs = np.array(xs, dtype=np.float64)
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


class FixedMatrices(NamedTuple):
    """Matrices held at a value in a posterior (:func:`boundary_fixed`; ``fixed`` of
    :func:`make_log_posterior`): one field per name of :data:`~hapid.fit.MATRIX_NAMES`, each
    an ``(n, n)`` float64 matrix in physical units (kg, N·s/m, N/m) or ``None`` when that
    matrix is sampled. :meth:`held` gives the held ones by name."""

    M_H: np.ndarray | None = None
    B_H: np.ndarray | None = None
    K_H: np.ndarray | None = None
    M_M: np.ndarray | None = None
    B_M: np.ndarray | None = None
    K_M: np.ndarray | None = None

    def held(self) -> dict[str, np.ndarray]:
        """``{name: (n, n) matrix}`` of the held matrices, in :data:`MATRIX_NAMES` order."""
        return {k: v for k, v in self._asdict().items() if v is not None}


def boundary_fixed(nls_result) -> FixedMatrices:
    """The NLS fit's matrices at the PSD boundary (physical units, projected to PSD) as
    :class:`FixedMatrices`, to pass as ``fixed`` to :func:`make_log_posterior`; the others
    ``None``."""
    m = project_pd(nls_result.model, floor=0.0)
    mats = dict(zip(MATRIX_NAMES, (m.hand.M, m.hand.B, m.hand.K, m.mechanism.M, m.mechanism.B,
                                   m.mechanism.K), strict=True))  # fmt: skip
    return FixedMatrices(**{name: np.asarray(mats[name]) for name in nls_result.boundary})
