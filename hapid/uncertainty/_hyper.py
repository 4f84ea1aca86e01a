# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Fixing the model-error hyperparameters of a :class:`~hapid.uncertainty._likelihood.LogPosterior`,
the step between building the posterior and sampling it: :func:`fix_hyperparameters` does
what the model-error object's ``hyper`` says; :func:`fix_gp_hyper` holds them at given values
(the matrices' likelihood becomes a quadratic form), :func:`marginal_hyper` finds the mode of
their marginal likelihood (the matrices integrated out in closed form,
:func:`log_marginal_likelihood`).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..fit._result import NLSResult
from ._gp import N_GP_CORR_HYPER, N_GP_HYPER, gp_corr_covariance
from ._likelihood import LogPosterior
from ._mode import initial_point, posterior_mode
from ._model_error import GP, GPCorr


def fix_hyperparameters(post: LogPosterior, reference=None) -> LogPosterior:
    """``post`` with its model error's hyperparameters fixed as ``post.error.hyper`` says
    (GP kinds; any other posterior is returned as it is): ``"sample"`` — left sampled;
    ``"marginal"`` — at the mode of their marginal posterior (:func:`marginal_hyper`, from
    the prior means); ``"map"`` — at the joint posterior mode from the NLS start
    (``reference``, an :class:`~hapid.fit.NLSResult`); numbers — at those values
    (:func:`fix_gp_hyper`)."""
    if (
        not isinstance(post.error, GP)
        or post.error.hyper == "sample"
        or post.hyper_fixed is not None
    ):
        return post
    how = post.error.hyper
    if how == "marginal":
        h, _ = marginal_hyper(post, jnp.asarray(post.hyper_mean()))
        return fix_gp_hyper(post, h)
    if how == "map":
        if not isinstance(reference, NLSResult):
            raise ValueError("hyper='map' needs reference= the NLSResult (the start of the mode "
                             "search); use hyper='sample' or fixed numbers otherwise")  # fmt: skip
        xm, _ = posterior_mode(post, initial_point(post, reference))
        return fix_gp_hyper(post, xm[post.n_free :])
    return fix_gp_hyper(post, how)


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
    if not isinstance(post.error, GP):
        raise ValueError("fix_gp_hyper: the posterior has no gp model error")
    h = jnp.asarray(hyper, dtype=jnp.float64)
    corr = isinstance(post.error, GPCorr)
    full = N_GP_CORR_HYPER if corr else N_GP_HYPER
    if h.shape not in ((6,), (N_GP_HYPER,), (full,)) or not bool(jnp.all(jnp.isfinite(h))):
        raise ValueError(f"fix_gp_hyper: hyper must be 6, {N_GP_HYPER} or {full} finite "
                         f"numbers, got shape {h.shape}")  # fmt: skip
    h = jnp.concatenate([h, jnp.zeros(full - h.shape[0])])
    base = dataclasses.replace(post, hyper_fixed=h, quad_R=None, quad_mu=None, quad_ll0=None)
    R, mu, ll0 = _quadratic_form_corr(base, h) if corr else _quadratic_form(base, h)
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
    with the hyperparameters' prior; ``GPCorr(hyper="marginal")``, the default).

    For fixed hyperparameters the residual ``r(v) = y₀ − J v`` is linear in the free matrix
    entries ``v`` (matrix parameterization) and Gaussian, so with the prior
    ``v ~ N(0, prior_scale² I)`` (the PSD restriction left out)

        log p(data | h) = c − ‖z‖² + ½ bᵀ P⁻¹ b − ½ log det P − (q/2) log prior_scale²,

    ``z = L⁻¹ y₀``, ``W = L⁻¹ J`` per element (``C = L Lᴴ``), ``b = 2 Re Σ Wᴴ z``,
    ``P = 2 Re Σ Wᴴ W + I/prior_scale²``, ``c = −Σ log det(π C)``. Unlike the joint mode
    (``hyper="map"``), whose θ absorbs part of the misfit and whose model-error scales
    come out small, this counts the ``q`` fitted degrees of freedom (as REML does).
    BFGS (optimistix) from ``h0``."""
    if not isinstance(post.error, GPCorr) or post.n_tau == 0:
        raise ValueError("marginal_hyper: needs a GPCorr posterior with sampled hyperparameters")
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
    w = jnp.imag(post.s)
    C = gp_corr_covariance(jnp.log(w), *post.error_amplitudes(), post.var_H, post.var_T,
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
    prior = post.unconstrained()
    x_th = jnp.zeros(post.n_free)

    def neg(h, _):
        v = _log_marginal_compact(post, h, y0, Jc, idx, q) + prior.log_prior(
            jnp.concatenate([x_th, h])
        )
        return -jnp.where(jnp.isfinite(v), v, -1e300)

    sol = optx.minimise(neg, optx.BFGS(rtol=1e-9, atol=1e-9), h0, max_steps=max_steps, throw=False)
    return sol.value, sol.result == optx.RESULTS.successful
