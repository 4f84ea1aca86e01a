# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The posterior's mode: start point from an NLS fit, BFGS mode search, walker checks.

:func:`initial_point` builds the start ``x0`` from an :class:`~hapid.fit.NLSResult`;
:func:`posterior_mode` finds the mode by BFGS (optimistix) on ``−log p``; the Laplace
approximation of :mod:`hapid.uncertainty._sampler` adds the Hessian there (``_map_hessian``).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .. import _config  # noqa: F401  (float64)
from ..fit._pd import n_from_params
from ..fit._result import NLSResult
from ._coords import diag_positions, theta_to_matrix
from ._likelihood import LogPosterior


def _canonical_with_cov(theta, cov):
    """Flip factor columns so diagonals are ≥ 0; the same linear sign map on ``cov``."""
    n = n_from_params(theta.shape[-1])
    rows, cols = np.tril_indices(n)
    t = len(rows)
    th = np.asarray(theta, dtype=float)
    sign = np.ones_like(th)
    diag = diag_positions(n)
    for k in range(6):
        for j in range(n):
            if th[diag[k * n + j]] < 0:  # flip column j of factor k
                sign[k * t + np.flatnonzero(cols == j)] *= -1.0
    return th * sign, np.asarray(cov) * np.outer(sign, sign)


def posterior_mode(post: LogPosterior, x0, *, max_steps: int = 3000, rtol: float = 1e-9,
                   atol: float = 1e-9) -> tuple[np.ndarray, bool]:  # fmt: skip
    """``(x_map (d,), converged)``: BFGS (optimistix) on ``−log p`` of the PSD-unconstrained
    posterior from ``x0`` — :func:`laplace_posterior` without the Hessian."""
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    if x0.shape != (post.dim,) or not np.isfinite(float(post.unconstrained()(x0))):
        raise ValueError(f"posterior_mode: x0 must be ({post.dim},) with a finite log-posterior")
    x, ok = _map(post.unconstrained(), x0, max_steps, rtol, atol)
    return np.asarray(x), bool(ok)


@eqx.filter_jit
def _map(post, x0, max_steps, rtol, atol):
    nlp = lambda x, args: -post(x)  # noqa: E731
    sol = optx.minimise(nlp, optx.BFGS(rtol=rtol, atol=atol), x0, max_steps=max_steps, throw=False)
    return sol.value, sol.result == optx.RESULTS.successful


@eqx.filter_jit
def _map_hessian(post, x0, max_steps, rtol, atol):
    nlp = lambda x, args: -post(x)  # noqa: E731
    sol = optx.minimise(nlp, optx.BFGS(rtol=rtol, atol=atol), x0, max_steps=max_steps, throw=False)
    x = sol.value
    H = jax.hessian(lambda z: -post(z))(x)
    return x, sol.stats["num_steps"], sol.result == optx.RESULTS.successful, H


def initial_point(post: LogPosterior, nls_result: NLSResult | None = None) -> np.ndarray:
    """A start ``x0`` (d,): the (canonical) NLS θ, then the prior means of log τ; without an
    NLS result, a noise-weighted :func:`hapid.fit.fit_nls` is not attempted — pass one."""
    if nls_result is None:
        raise ValueError("initial_point: pass an NLSResult (the NLS optimum is the start)")
    th = np.asarray(nls_result.theta)
    if th.shape != (post.n_theta,):
        raise ValueError(
            f"the NLS result has θ of length {th.shape[-1]} (n = {n_from_params(th.shape[-1])}), "
            f"the posterior expects {post.n_theta} (n = {post.n})"
        )
    if not np.allclose(
        np.asarray(nls_result.scale.z_ref), np.asarray(post.scale.z_ref)
    ) or not np.allclose(np.asarray(nls_result.scale.omega_ref), np.asarray(post.scale.omega_ref)):
        raise ValueError(
            "the NLS result's scale differs from the posterior's: build it with scale=nls.scale"
        )
    th, _ = _canonical_with_cov(th, np.eye(th.shape[0]))
    th = theta_to_matrix(th, post.n)
    x0 = np.concatenate([post.free_part(th), post.hyper_mean()])
    return post.project(x0)  # a boundary matrix's −1e-17 eigenvalue is outside the cone


def check_initial_state(post: LogPosterior, x0: np.ndarray, log_prob_fn=None) -> np.ndarray:
    """Validate walkers ``(W, d)``: finite, ``W ≥ 2d``, finite log-probability. Returns
    their log-probabilities. Raises ``ValueError`` naming the problem."""
    x0 = np.asarray(x0, dtype=np.float64)
    d = post.dim
    if x0.ndim != 2 or x0.shape[1] != d:
        raise ValueError(f"initial state must be (n_walkers, {d}), got shape {x0.shape}")
    W = x0.shape[0]
    if W < 2 * d:
        raise ValueError(
            f"{W} walkers for d = {d} parameters: emcee's ensemble moves need at least 2·d = "
            f"{2 * d} walkers"
        )
    if not np.all(np.isfinite(x0)):
        bad = np.argwhere(~np.isfinite(x0))[0]
        w, k = int(bad[0]), int(bad[1])
        raise ValueError(f"initial state contains NaN or inf (walker {w}, parameter {k})")
    lp = (post.log_prob_numpy if log_prob_fn is None else log_prob_fn)(x0)
    if not np.all(np.isfinite(lp)):
        k = int(np.flatnonzero(~np.isfinite(lp))[0])
        raise ValueError(f"initial state: walker {k} has a non-finite log-probability ({lp[k]})")
    return lp
