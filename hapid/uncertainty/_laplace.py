# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Laplace approximations of the posterior.

- :func:`laplace_samples` — the fast path: Gaussian draws ``N(θ̂, Σ_NLS)`` from an
  :class:`~hapid.fit.NLSResult` (θ only, no model-error parameters), the fit's PSD-boundary
  matrices held and the rest drawn from the Gaussian conditioned on them.
- :func:`laplace_posterior` — the mode of a :class:`LogPosterior` (BFGS from the NLS optimum)
  and the inverse Hessian there.
- :func:`posterior_laplace_samples` — draws of that Gaussian as :class:`PosteriorSamples`.
"""

from __future__ import annotations

import dataclasses
import enum

import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._plain import jsonable
from ..fit._pd import MATRIX_NAMES, n_from_params
from ..fit._result import NLSResult
from ..samples import PosteriorSamples
from ._coords import fold_theta
from ._likelihood import LogPosterior, param_names
from ._mode import (
    _canonical_with_cov,
    _map_hessian,
    initial_point,
)

# --- Laplace ---------------------------------------------------------------------------


def _check_key(key):
    if isinstance(key, int):
        return jax.random.PRNGKey(key)
    return key


def _held_boundary(cov, n: int, boundary) -> np.ndarray:
    """``cov`` conditioned on the factor entries of the matrices in ``boundary`` (names of
    :data:`~hapid.fit._pd.MATRIX_NAMES`) staying at the fit's values: the Schur complement
    ``Σ_oo − Σ_of Σ_ff⁺ Σ_fo`` on the other entries, zero rows and columns for the held ones.

    Why: at the PSD boundary a matrix's Cholesky factor is ≈ 0, where the model does not
    depend on it to first order, so ``σ̂²(JᵀJ)⁺`` gives it a standard deviation of ~10⁴ (in
    scaled units; cu5's ``K_M`` on the paper protocol) and a draw's matrix ``LLᵀ`` lands 10⁵–
    10⁸ times the fit's size — every draw. ``hapid posterior`` holds these matrices
    (:func:`~hapid.uncertainty.boundary_fixed`); this is the same rule for the Laplace draws
    of a fit."""
    t = n * (n + 1) // 2  # factor entries per matrix, in MATRIX_NAMES order
    held = np.repeat([name in boundary for name in MATRIX_NAMES], t)
    if not held.any():
        return cov
    o, f = ~held, held
    S_of = cov[np.ix_(o, f)]
    cond = (
        cov[np.ix_(o, o)]
        - S_of @ np.linalg.pinv(cov[np.ix_(f, f)], rcond=1e-12, hermitian=True) @ S_of.T
    )
    out = np.zeros_like(cov)
    out[np.ix_(o, o)] = 0.5 * (cond + cond.T)
    return out


def laplace_samples(
    nls_result: NLSResult, n_samples: int, key=0, *, fix_boundary: bool = True
) -> PosteriorSamples:
    """Fast path: ``n_samples`` draws of θ from ``N(θ̂, Σ)`` of an NLS fit (no MCMC).

    ``Σ = nls_result.covariance`` (``σ̂²(JᵀJ)⁺``). The NLS θ̂ is first made canonical (column
    signs flipped so diagonals are ≥ 0, same model, same linear map on Σ); draws are then
    folded (``|diag|``). With noise weights this is the Laplace approximation of the
    pure-noise posterior under a flat prior; with relative/blend weights its σ̂² absorbs the
    model error as a single scale. ``key``: a JAX PRNG key or an int seed.

    ``fix_boundary`` (default, as ``hapid posterior``): the matrices the fit put on the PSD
    boundary (``nls_result.boundary``) are held at the fit's value and the other entries drawn
    from the Gaussian conditioned on that (:func:`_held_boundary`: without it every draw of
    cu5's paper fit has a device stiffness 10⁵–10⁸ times the fit's). ``False``: the plain
    ``N(θ̂, Σ)``.
    """
    if not isinstance(nls_result, NLSResult):
        raise ValueError(f"laplace_samples: expected an NLSResult, got {type(nls_result).__name__}")
    if np.ndim(nls_result.theta) != 1:
        raise ValueError("laplace_samples: an unbatched NLSResult is required")
    if not (isinstance(n_samples, int | np.integer) and n_samples > 0):
        raise ValueError(f"n_samples must be a positive int, got {n_samples!r}")
    theta, cov = _canonical_with_cov(
        np.asarray(nls_result.theta), np.asarray(nls_result.covariance)
    )
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(cov))):
        raise ValueError("laplace_samples: the NLS result has a non-finite θ or covariance")
    n = n_from_params(theta.shape[0])
    if fix_boundary and nls_result.boundary:
        cov = _held_boundary(cov, n, tuple(nls_result.boundary))
    draws = _mvn(_check_key(key), theta, cov, n_samples)
    return PosteriorSamples(
        samples=fold_theta(draws),
        log_prob=np.full(n_samples, np.nan),
        scale=nls_result.scale,
        n=n,
        names=tuple(param_names(n)),
        diagnostics={"method": "laplace_nls", "mean": theta, "cov": cov},
    )


def _mvn(key, mean, cov, k):
    """Draws from N(mean, cov) via a symmetric square root (PSD cov allowed)."""
    lam, V = np.linalg.eigh(0.5 * (cov + cov.T))
    root = V * np.sqrt(np.clip(lam, 0.0, None))
    z = np.asarray(jax.random.normal(key, (k, mean.shape[0])))
    return mean + z @ root.T


class ModeStatus(enum.StrEnum):
    """Verdict of a :class:`LaplacePosterior`: did the mode search converge."""

    CONVERGED = "converged"
    NOT_CONVERGED = "not converged"


@dataclasses.dataclass(frozen=True)
class LaplacePosterior:
    """The Laplace approximation of a :class:`LogPosterior` (:func:`laplace_posterior`).

    - ``mean``: ``(d,)``, the MAP in the posterior's sampled coordinates (matrix θ, scaled
      units, then the model-error coordinates) — the Gaussian's mean.
    - ``cov``: ``(d, d)``, the Gaussian's covariance (same coordinates).
    - ``steps``: BFGS steps taken; ``converged``: the search met its tolerances.
    - ``log_prob``: log posterior (PSD-unconstrained) at the MAP; ``mode_in_cone``: the MAP
      is inside the PSD cone (finite constrained log posterior).

    ``status`` (:class:`ModeStatus`): ``converged`` or ``not converged``; ``ok`` when
    converged. :meth:`info` is the diagnostics entry the samples carry.
    """

    mean: np.ndarray
    cov: np.ndarray
    steps: int
    converged: bool
    log_prob: float
    mode_in_cone: bool

    @property
    def status(self) -> ModeStatus:
        return ModeStatus.CONVERGED if self.converged else ModeStatus.NOT_CONVERGED

    @property
    def ok(self) -> bool:
        return self.status is ModeStatus.CONVERGED

    def info(self) -> dict:
        """``{"steps", "converged", "log_prob", "mode_in_cone"}`` as Python values (NaN
        kept): the ``laplace`` entry of a :class:`PosteriorSamples`' diagnostics."""
        return {"steps": self.steps, "converged": self.converged, "log_prob": self.log_prob,
                "mode_in_cone": self.mode_in_cone}  # fmt: skip

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``dim`` (``d``), then :meth:`info` (a
        non-finite ``log_prob`` is ``None``)."""
        return jsonable({"status": self.status, "ok": self.ok, "dim": int(self.mean.shape[0]),
                         **self.info()})  # fmt: skip


def laplace_posterior(
    post: LogPosterior, x0, *, max_steps: int = 3000, rtol: float = 1e-9, atol: float = 1e-9
) -> LaplacePosterior:
    """MAP and Laplace covariance of a :class:`LogPosterior`: a :class:`LaplacePosterior`
    (``mean (d,)``, ``cov (d, d)``, the search's ``steps`` and ``converged``, ``log_prob`` at
    the MAP, ``mode_in_cone``).

    BFGS (optimistix) on ``−log p`` from ``x0`` (e.g. the NLS θ followed by the prior mean
    of log τ). The covariance is the inverse Hessian with its eigenvalues floored at the
    prior precision ``1/prior_scale²`` (the prior alone contributes that much curvature; a
    negative curvature at a kink ``|θ_jj| = 0`` would otherwise give nonsense).
    """
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    if x0.shape != (post.dim,):
        raise ValueError(f"laplace_posterior: x0 must be ({post.dim},), got {x0.shape}")
    if not bool(jnp.all(jnp.isfinite(x0))):
        raise ValueError("laplace_posterior: x0 contains NaN or inf")
    if not np.isfinite(float(post(x0))):
        raise ValueError("laplace_posterior: the log-posterior at x0 is not finite")
    post_u = post.unconstrained()  # matrix coordinates: the Gaussian before the PSD cone
    xm, steps, ok, H = _map_hessian(post_u, x0, max_steps, rtol, atol)
    xm, H = np.asarray(xm), np.asarray(H)
    lam, V = np.linalg.eigh(0.5 * (H + H.T))
    floor = 1.0 / post.prior_scale**2
    lam = np.maximum(lam, floor)
    cov = (V / lam) @ V.T
    return LaplacePosterior(
        mean=xm,
        cov=cov,
        steps=int(steps),
        converged=bool(ok),
        log_prob=float(post_u(jnp.asarray(xm))),
        mode_in_cone=bool(np.isfinite(float(post(jnp.asarray(xm))))),
    )


def posterior_laplace_samples(post: LogPosterior, n_samples: int, init, key=0) -> PosteriorSamples:
    """Fast path from a :class:`LogPosterior`: its Laplace Gaussian (:func:`laplace_posterior`
    from ``init``, an :class:`NLSResult` or a start ``x0``), ``n_samples`` draws, each moved
    into the PSD cone (:meth:`LogPosterior.project`; matrix parameterization) and returned as
    canonical Cholesky θ with the model-error coordinates.

    In matrix coordinates this is the Gaussian of the untruncated linear-Gaussian posterior
    (exact for fixed τ) *projected* onto the cone — not the truncated posterior emcee samples:
    draws of a matrix at the PSD boundary pile up on the boundary instead of being reweighted.
    Fine for margins and bands; use :func:`sample_posterior` for calibrated intervals.
    """
    if not (isinstance(n_samples, int | np.integer) and n_samples > 0):
        raise ValueError(f"n_samples must be a positive int, got {n_samples!r}")
    x0 = (
        initial_point(post, init)
        if isinstance(init, NLSResult)
        else np.asarray(init, dtype=np.float64)
    )
    lp = laplace_posterior(post, x0)
    draws = post.project(_mvn(_check_key(key), lp.mean, lp.cov, n_samples))
    theta, extra = post.split(draws)
    return PosteriorSamples(
        samples=np.concatenate([theta, extra], axis=1),
        log_prob=np.asarray(post.log_prob_numpy(draws)),
        scale=post.scale,
        n=post.n,
        names=tuple(param_names(post.n, post.error)),
        diagnostics={"method": "laplace_matrix", "laplace": lp.info()},
        predictive=post.predictive_data(),
    )
