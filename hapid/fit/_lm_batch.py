# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""Levenberg–Marquardt on the compressed NLS residual, lean enough to batch.

``fit_nls`` runs optimistix's ``LevenbergMarquardt`` (``linear_solver=lx.Normal(lx.Cholesky())``)
through :func:`hapid.fit._iterate.iterate` on the :class:`~hapid.fit._compress.CompressedProblem`.
Under ``vmap`` that machinery costs per fit what it costs alone: each step materializes the
damped operator ``[J; √λ I]`` (``(m + p) × p``) by ``p`` batched JVPs and forms its normal
matrix densely, and the Laplace covariance is a ``p × p`` ``eigh`` per fit.

This module is the same algorithm, step for step, written on the structure of the compressed
residual ``r_t = R_t a_t(θ) − y_t`` (element ``t``, ``a_t`` the six matrix entries):

- ``J[(t, r), (k, α)] = R_t[r, k]·D_k[t, α]`` with ``D_k = ∂(L_k L_kᵀ)_t/∂θ_k`` a constant 0/1
  tensor times ``θ_k`` (one small matmul);
- ``JᵀJ[(k, α), (l, β)] = Σ_t G_t[k, l]·D_k[t, α]·D_l[t, β]`` with ``G_t = R_tᵀR_t`` formed once
  per fit — six batched ``(p × t)·(t × t)`` matmuls instead of the dense ``p × m × p`` product;
- the trust-region test, the damping ``λ = 1/step_size``, the Cauchy termination and the
  stagnation rule are optimistix's ``ClassicalTrustRegion`` / ``DampedNewtonDescent`` /
  ``cauchy_termination`` and ``iterate``'s, with the same constants and the same order of
  operations; the damped system ``(JᵀJ + λI) x = Jᵀr`` is solved by the same Cholesky calls
  lineax makes. The step count and status equal ``fit_nls``'s and the costs agree to rounding
  (``tests/test_fit_batch.py``).

:func:`lm_compressed` is one fit (vmappable); :func:`covariance_batch` the Laplace covariance
of a batch, through the structured inverse ``(JᵀJ)⁻¹ = D⁻¹H⁻¹D⁻ᵀ`` where the information matrix
is provably far from singular and ``pinv_psd`` (``eigh``) only for the fits where it is not.

What still runs matrix by matrix under ``vmap``: the ``p × p`` damped Cholesky of each step
(LAPACK ``potrf``/``trsm``, ~30 µs at p = 90 — an XLA-op Cholesky with unrolled columns
measured ~1 ms per matrix and minutes of compile) and, once per fit, the set-up's small QR
and ``eigh`` (``compress``, ``project_pd``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from jax import lax
from jaxtyping import Array, Float

from .._linalg import pinv_psd
from ._compress import CompressedProblem
from ._result import CONVERGED, FAILED, MAX_STEPS

# optimistix.ClassicalTrustRegion's defaults (Gould et al.), used by LevenbergMarquardt
HIGH_CUTOFF, LOW_CUTOFF, HIGH_CONSTANT, LOW_CONSTANT = 0.99, 0.01, 3.5, 0.25
#: covariance_batch uses the structured inverse when tr(F)·‖F⁻¹‖_F (≥ the condition number)
#: is below this; pinv_psd drops eigenvalues below 1e-12 × the largest, so up to 1e10 the
#: two are the same matrix (100× margin for rounding)
COND_CHOLESKY_MAX = 1e10


@functools.cache
def entry_jacobian_selection(n: int) -> np.ndarray:
    """``S`` ``(t·t, t)``, 0/1/2: ``D[t_, α] = Σ_m S[t_·t + α, m] θ_k[m]`` is the Jacobian of the
    lower-triangle entries ``(L Lᵀ)[i, j]`` (``t_ = (i, j)``) w.r.t. the factor entries
    ``L[a, c]`` (``α = (a, c)``), both in ``numpy.tril_indices`` order (``t = n(n+1)/2``).

    ``∂(L Lᵀ)[i, j]/∂L[a, c] = δ_ai L[j, c] + δ_aj L[i, c]`` (zero above the diagonal of L).
    """
    rows, cols = np.tril_indices(n)
    T = len(rows)
    idx = -np.ones((n, n), dtype=int)
    idx[rows, cols] = np.arange(T)
    S = np.zeros((T, T, T))
    for t, (i, j) in enumerate(zip(rows, cols, strict=True)):
        for al, (a, c) in enumerate(zip(rows, cols, strict=True)):
            if a == i and c <= j:
                S[t, al, idx[j, c]] += 1.0
            if a == j and c <= i:
                S[t, al, idx[i, c]] += 1.0
    return S.reshape(T * T, T)


def gram(work: CompressedProblem) -> Float[Array, "t 6 6"]:
    """``G_t = R_tᵀ R_t`` of every element (constant during a fit)."""
    return jnp.einsum("trk,trl->tkl", work.R, work.R)


def entry_jacobian(theta: Float[Array, " p"], n: int) -> Float[Array, "6 t t"]:
    """``D[k, t, α] = ∂(L_k L_kᵀ)[t]/∂θ_k[α]`` (lower triangular in ``(t, α)``)."""
    T = n * (n + 1) // 2
    S = jnp.asarray(entry_jacobian_selection(n), dtype=theta.dtype)
    return (theta.reshape(6, T) @ S.T).reshape(6, T, T)


def normal_matrix(D, G) -> Float[Array, "p p"]:
    """``JᵀJ`` (``(p, p)``) from ``D`` (:func:`entry_jacobian`) and ``G`` (:func:`gram`):
    ``[(k, α), (l, β)] = Σ_t D[k, t, α] G[t, k, l] D[l, t, β]``, six batched matmuls."""
    T = D.shape[-1]
    W = jnp.einsum("kta,tkl->lkat", D, G).reshape(6, 6 * T, T)
    F = jnp.matmul(W, D)  # (l, (k, α), β)
    return jnp.transpose(F.reshape(6, 6 * T, T), (1, 0, 2)).reshape(6 * T, 6 * T)


def derivatives(work: CompressedProblem, G, theta: Float[Array, " p"]):
    """``(r, D, Jᵀr, JᵀJ)`` of the compressed residual at ``theta``.

    ``r`` ``(m,)`` is ``work(theta)`` (last entry ``√c₀``, whose row of ``J`` is zero); the
    Jacobian ``J[(t, r), (k, α)] = R_t[r, k] D[k, t, α]`` is never formed: ``Jᵀr`` and
    ``JᵀJ`` (``(p, p)``, :func:`normal_matrix`) come from ``D`` (:func:`jvp` gives ``J δ``).
    """
    r, D, g = residual_gradient(work, theta)
    return r, D, g, normal_matrix(D, G)


def residual_gradient(work: CompressedProblem, theta: Float[Array, " p"]):
    """``(r, D, Jᵀr)``: :func:`derivatives` without ``JᵀJ``."""
    n = work.n
    T = n * (n + 1) // 2
    D = entry_jacobian(theta, n)
    r = work(theta)
    u = jnp.einsum("trk,tr->kt", work.R, r[:-1].reshape(T, 6))  # R_tᵀ r_t
    g = jnp.einsum("kta,kt->ka", D, u).reshape(6 * T)
    return r, D, g


def jvp(work: CompressedProblem, D, delta: Float[Array, " p"]) -> Float[Array, " m"]:
    """``J δ`` (``(m,)``, last entry 0) of the compressed residual, ``D`` from
    :func:`derivatives` at the linearization point."""
    T = D.shape[-1]
    da = jnp.einsum("kta,ka->tk", D, delta.reshape(6, T))  # change of the six entries
    Jd = jnp.einsum("trk,tk->tr", work.R, da).reshape(6 * T)
    return jnp.concatenate([Jd, jnp.zeros((1,), delta.dtype)])


def _cauchy(rtol, atol, y, y_diff, f, f_diff):
    """optimistix.cauchy_termination with its max norm."""
    y_scale = atol + rtol * jnp.abs(y)
    f_scale = atol + rtol * jnp.abs(f)
    y_conv = jnp.max(jnp.abs(y_diff) / y_scale) < 1
    f_conv = jnp.max(jnp.abs(f_diff) / f_scale) < 1
    return y_conv & f_conv


def damped_solve(F, g, step_size):
    """optimistix ``damped_newton_step`` with ``lx.Normal(lx.Cholesky())``: solve
    ``(JᵀJ + λI) x = Jᵀr``, ``λ = 1/step_size`` (the largest float when ``step_size ≤ eps``)."""
    eps = jnp.finfo(step_size.dtype).eps
    pred = step_size > eps
    safe = jnp.where(pred, step_size, 1.0)
    lam = jnp.where(pred, 1.0 / safe, jnp.finfo(step_size.dtype).max)
    root = jnp.sqrt(lam)
    A = F + (root * root) * jnp.eye(F.shape[-1], dtype=F.dtype)
    factor, _ = jsl.cho_factor(A)
    return jsl.cho_solve((factor, False), g)


def lm_compressed(
    work: CompressedProblem,
    theta0: Float[Array, " p"],
    rtol,
    atol,
    max_steps,
    ftol,
    patience,
) -> tuple[Array, Array, Array]:
    """One Levenberg–Marquardt fit of ``work`` from ``theta0``: ``(theta, n_steps, code)``.

    The same iterates as ``iterate(optx.LevenbergMarquardt(rtol, atol,
    linear_solver=lx.Normal(lx.Cholesky())), ...)`` with the stagnation rule (``ftol`` over
    ``patience`` steps) — see the module docstring. Vmappable: ``jax.vmap`` turns the loop
    into one batched loop that runs until every fit has stopped (a stopped fit is frozen).
    """
    G = gram(work)
    p = theta0.shape[-1]
    dt = theta0.dtype
    m = work.y.size + 1
    T = work.y.shape[0]
    zero_r = jnp.zeros((m,), dt)
    c0 = work.cost(theta0)
    carry0 = dict(
        y=theta0, y_eval=theta0, k=jnp.array(0), step=jnp.array(1.0, dt), first=jnp.array(True),
        r=zero_r, D=jnp.zeros((6, T, T), dt), g=jnp.zeros((p,), dt),
        term=jnp.array(False), nonfinite=jnp.array(False), ref=c0, since=jnp.array(0),
        stalled=jnp.array(False), y_best=theta0, c_best=c0,
    )  # fmt: skip

    def cond(c):
        return (~c["term"]) & (~c["stalled"]) & (~c["nonfinite"]) & (c["k"] < max_steps)

    def body(c):
        r_e, D_e, g_e = residual_gradient(work, c["y_eval"])
        # ClassicalTrustRegion.step, with the last accepted point's residual and Jacobian
        y_diff = c["y_eval"] - c["y"]
        Jd = jvp(work, c["D"], y_diff)
        rtr = jnp.sum(c["r"] ** 2)
        pred_red = 0.5 * (jnp.sum((Jd + c["r"]) ** 2) - rtr)
        f_min_diff = 0.5 * jnp.sum(r_e**2) - 0.5 * rtr
        accept = f_min_diff <= LOW_CUTOFF * pred_red
        good = (f_min_diff < HIGH_CUTOFF * pred_red) & (pred_red < 0) & ~c["first"]
        accept = accept | c["first"]
        mul = jnp.where(good, HIGH_CONSTANT, 1.0)
        mul = jnp.where(accept, mul, LOW_CONSTANT)
        step = mul * c["step"]
        # AbstractGaussNewton.step: accepted / rejected branches, then the damped descent
        term = accept & _cauchy(rtol, atol, c["y_eval"], y_diff, r_e, r_e - c["r"])
        sel = lambda a, b: jnp.where(accept, a, b)  # noqa: E731
        y = sel(c["y_eval"], c["y"])
        r, D, g = sel(r_e, c["r"]), sel(D_e, c["D"]), sel(g_e, c["g"])
        # JᵀJ of the accepted point, formed from its D (carrying D, not the p × p matrix)
        y_eval = y - damped_solve(normal_matrix(D, G), g, step)
        # iterate's finite check and stagnation rule on the accepted point's cost
        nonfinite = ~jnp.all(jnp.isfinite(y))
        cst = 0.5 * jnp.sum(r**2)
        improved = cst < c["ref"] * (1.0 - ftol)
        ref = jnp.where(improved, cst, jnp.minimum(c["ref"], cst))
        since = jnp.where(improved, 0, c["since"] + 1)
        better = jnp.isfinite(cst) & (cst < c["c_best"])
        return dict(
            y=y, y_eval=y_eval, k=c["k"] + 1, step=step, first=jnp.array(False), r=r, D=D, g=g,
            term=term, nonfinite=nonfinite, ref=ref, since=since,
            stalled=since >= patience, y_best=jnp.where(better, y, c["y_best"]),
            c_best=jnp.where(better, cst, c["c_best"]),
        )  # fmt: skip

    c = lax.while_loop(cond, body, carry0)
    y, term, stalled, y_best, c_best = c["y"], c["term"], c["stalled"], c["y_best"], c["c_best"]
    successful = ~c["nonfinite"]
    c_last = work.cost(y)
    diverged = ~(c_last <= c_best * (1.0 + 10.0 * ftol) + 1e-300)
    ok = (term | stalled) & successful & ~(stalled & ~term & diverged)
    y = jnp.where(stalled & diverged, y_best, y)
    maxed = successful & ~ok & ~(stalled & ~term & diverged)
    code = jnp.where(ok, CONVERGED, jnp.where(maxed, MAX_STEPS, FAILED))
    return y, c["k"], code


def information(work: CompressedProblem, theta: Float[Array, " p"]):
    """``(JᵀJ, cost)`` of the compressed residual at ``theta`` (one fit)."""
    r, _, _, F = derivatives(work, gram(work), theta)
    return F, 0.5 * jnp.sum(r**2)


def information_trace(work: CompressedProblem, theta: Float[Array, " p"]):
    """``(tr(JᵀJ), cost)`` without forming ``JᵀJ``: ``Σ_t Σ_k G_t[k, k]·‖D[k, t, :]‖²``."""
    D = entry_jacobian(theta, work.n)
    G = gram(work)
    tr = jnp.sum(jnp.diagonal(G, axis1=-2, axis2=-1).T * jnp.sum(D**2, axis=-1))
    return tr, 0.5 * jnp.sum(work(theta) ** 2)


def tril_inverse(A: Float[Array, "... k k"]) -> Float[Array, "... k k"]:
    """Inverse of lower-triangular matrices by forward substitution, in plain XLA ops (one
    ``fori_loop`` over rows, vectorized over the leading axes). Non-finite where singular."""
    k = A.shape[-1]
    eye = jnp.eye(k, dtype=A.dtype)

    def row(i, X):
        a = lax.dynamic_index_in_dim(A, i, axis=-2, keepdims=False)  # (..., k)
        e = lax.dynamic_index_in_dim(eye, i, axis=0, keepdims=False)
        d = lax.dynamic_index_in_dim(a, i, axis=-1, keepdims=False)
        new = (e - jnp.einsum("...c,...cj->...j", a, X)) / d[..., None]
        return lax.dynamic_update_index_in_dim(X, new, i, axis=-2)

    return lax.fori_loop(0, k, row, jnp.zeros_like(A))


def inverse_information(work: CompressedProblem, theta: Float[Array, " p"]):
    """``(JᵀJ)⁻¹`` from the structure, without factorizing the ``p × p`` matrix.

    ``JᵀJ = Dᵀ H D`` with ``D = blockdiag_k(D_k)`` and ``H = blockdiag_t(G_t)``. Each ``D_k``
    (``∂ tril(L Lᵀ)/∂ tril(L)``) is lower triangular in ``tril_indices`` order, with diagonal
    ``L[j, j]`` (``2 L[i, i]`` on the diagonal entries), so ``(JᵀJ)⁻¹ = D⁻¹ H⁻¹ D⁻ᵀ``:
    ``[(k, α), (l, β)] = Σ_t D_k⁻¹[α, t]·G_t⁻¹[k, l]·D_l⁻¹[β, t]`` with ``G_t⁻¹ = R_t⁻¹R_t⁻ᵀ``.
    Non-finite or huge where ``L`` has a zero diagonal (a matrix on the PSD boundary) or the
    data cannot identify an element (``R_t`` singular).
    """
    T = work.y.shape[0]
    D = entry_jacobian(theta, work.n)  # D[k, t, α], lower triangular
    Dinv = tril_inverse(D)  # Dinv[k, α, t]
    Xt = tril_inverse(jnp.swapaxes(work.R, -1, -2))  # (R_tᵀ)⁻¹
    Ginv = jnp.einsum("trk,trl->tkl", Xt, Xt)  # R⁻¹R⁻ᵀ
    W = jnp.einsum("kat,tkl->lkat", Dinv, Ginv).reshape(6, 6 * T, T)
    out = jnp.matmul(W, jnp.swapaxes(Dinv, -1, -2))  # (l, (k, α), β)
    return jnp.transpose(out.reshape(6, 6 * T, T), (1, 0, 2)).reshape(6 * T, 6 * T)


def covariance_batch(work: CompressedProblem, theta: Float[Array, "B p"]):
    """``(pinv_psd(JᵀJ), cost)`` of a batch of fits (``work`` and ``theta`` batched).

    A fit whose ``tr(F)·‖F⁻¹‖_F`` (an upper bound of the condition number of ``F = JᵀJ``) is
    below :data:`COND_CHOLESKY_MAX` has no eigenvalue ``pinv_psd`` would drop: its ``F⁻¹`` is
    :func:`inverse_information`. Only when some fit fails that test (a fitted matrix on the
    PSD boundary makes ``F`` singular) is ``pinv_psd`` (``eigh``) run, for the batch.
    """

    tr, cost = jax.vmap(information_trace)(work, theta)
    inv = jax.vmap(inverse_information)(work, theta)
    inv = 0.5 * (inv + jnp.swapaxes(inv, -1, -2))
    bound = tr * jnp.sqrt(jnp.sum(inv**2, axis=(-2, -1)))
    good = jnp.isfinite(bound) & (bound < COND_CHOLESKY_MAX)
    good = good & jnp.all(jnp.isfinite(inv), axis=(-2, -1))

    def fallback():
        F, _ = jax.vmap(information)(work, theta)
        return jnp.where(good[:, None, None], inv, jax.vmap(pinv_psd)(F))

    return lax.cond(jnp.all(good), lambda: inv, fallback), cost
