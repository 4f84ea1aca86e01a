# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""The NLS residual of Z_H, Z_T compressed to ``6 + 1`` rows per matrix element, same cost.

:class:`hapid.fit._nls.Problem`'s residual (without the P term) is *linear* in the six scaled
matrices ``A_k = L_k L_kᵀ``: for element ``(i, j)``

    e_H(ω) = W_H(ω, i, j)·(Σ_{k<3} c_k(s) A_k[i, j] − Z_H[i, j]),
    e_T(ω) = W_T(ω, i, j)·(Σ_{k<6} c_{k mod 3}(s) A_k[i, j] − Z_T[i, j]),

with ``c = (s², s, 1)``. Stacking real and imaginary parts over the band gives
``r_ij = M_ij a_ij − y_ij`` with ``a_ij = (A_0[i, j], …, A_5[i, j])`` (6 reals). The matrices
are symmetric, so elements ``(i, j)`` and ``(j, i)`` share ``a``: their rows are stacked and a
thin QR ``M = Q R`` (``R`` 6 × 6) gives, exactly,

    ‖r‖² = Σ_{i ≥ j} ‖R a_ij − Qᵀ y_ij‖² + c₀,    c₀ = Σ ‖y − Q Qᵀ y‖²,

so the compressed residual ``(R a − Qᵀy, √c₀)`` has the same cost, gradient and Gauss–Newton
matrix ``JᵀJ`` as the full one (``6·n(n+1)/2 + 1`` rows instead of ``4·n²·N``: 91 instead of
2800 on cu5 with the paper's 28 frequencies). Out-of-band frequencies have weight 0 and drop
out of ``M`` and ``y``: no masked rows are carried into the solver. The factorization is done
once per fit (the weights do not depend on θ).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


def _selection(n: int) -> np.ndarray:
    """``S`` ``(n·n, t)`` 0/1 with ``L.ravel() = S θ_k`` for a lower-triangular factor."""
    rows, cols = np.tril_indices(n)
    S = np.zeros((n * n, len(rows)))
    S[rows * n + cols, np.arange(len(rows))] = 1.0
    return S


def lower_entries(theta: Float[Array, " p"], n: int, eps=0.0) -> Float[Array, "t 6"]:
    """The lower-triangle entries ``(L_k L_kᵀ + eps·I)[i, j]``, ``i ≥ j``, of the six scaled
    matrices (:func:`hapid.fit._pd.theta_to_scaled`, same values): ``(t, 6)``.

    Written with constant 0/1 matmuls instead of index scatter/gather (exact: one nonzero
    term per entry), so its Jacobian and transpose stay dense small matmuls under ``vmap``.
    """
    S = jnp.asarray(_selection(n), dtype=theta.dtype)
    t = S.shape[1]
    L = (theta.reshape(6, t) @ S.T).reshape(6, n, n)
    A = L @ jnp.swapaxes(L, -1, -2) + eps * jnp.eye(n, dtype=theta.dtype)
    return A.reshape(6, n * n) @ S  # (6, t): entries (i, j), i ≥ j, in tril order


def _stack_real(x: Array) -> Array:
    """``(N, ...)`` complex → ``(2N, ...)`` real (real parts, then imaginary parts)."""
    return jnp.concatenate([jnp.real(x), jnp.imag(x)], axis=0)


class CompressedProblem(eqx.Module):
    """``r(θ) = (R a(θ) − y', √c₀)`` of an NLS problem without the P residual (see module).

    ``R`` ``(t, 6, 6)``, ``y`` ``(t, 6)`` with ``t = n(n+1)/2`` (lower-triangle elements in
    ``numpy.tril_indices`` order), ``c0`` the part of the cost no model can explain.
    """

    R: Float[Array, "t 6 6"]
    y: Float[Array, "t 6"]
    c0: Float[Array, ""]
    eps: Array
    n: int = eqx.field(static=True)

    def __call__(self, theta: Float[Array, " p"], args=None) -> Float[Array, " m"]:
        a = lower_entries(theta, self.n, self.eps).T  # (t, 6)
        r = jnp.einsum("tkl,tl->tk", self.R, a) - self.y
        return jnp.concatenate([r.ravel(), jnp.sqrt(self.c0)[None]])

    def cost(self, theta: Float[Array, " p"], args=None) -> Float[Array, ""]:
        """``½‖r(θ)‖²``, equal to the full problem's cost."""
        r = self(theta)
        return 0.5 * jnp.sum(r**2)


def compress(problem) -> CompressedProblem:
    """The :class:`CompressedProblem` of a :class:`hapid.fit._nls.Problem` (``P is None``).

    Jittable; the factorization is one batched thin QR of ``n(n+1)/2`` matrices of
    ``8N × 6`` (``N`` frequencies, masked ones with zero rows).
    """
    if problem.P is not None:
        raise ValueError("compress: the P residual is not linear in the matrices")
    n = problem.n
    s = problem.s[:, None, None]
    c = (s**2, s, jnp.ones_like(s))
    WH = jnp.broadcast_to(problem.W_H, problem.Z_H.shape)
    WT = jnp.broadcast_to(problem.W_T, problem.Z_T.shape)
    zero = jnp.zeros(problem.Z_H.shape, dtype=jnp.result_type(WH, s))
    colsH = [WH * ck for ck in c] + [zero] * 3  # 6 columns, (N, n, n) each
    colsT = [WT * ck for ck in c] * 2
    M = jnp.concatenate([_stack_real(jnp.stack(colsH, -1)), _stack_real(jnp.stack(colsT, -1))])
    y = jnp.concatenate([_stack_real(WH * problem.Z_H), _stack_real(WT * problem.Z_T)])
    # M (4N, n, n, 6), y (4N, n, n); element (i, j) and (j, i) share a_ij: stack their rows
    rows, cols = np.tril_indices(n)
    off = jnp.asarray(rows != cols, dtype=M.dtype)
    M_u = jnp.concatenate([M[:, rows, cols], off[:, None] * M[:, cols, rows]])  # (8N, t, 6)
    y_u = jnp.concatenate([y[:, rows, cols], off * y[:, cols, rows]])  # (8N, t)
    M_u = jnp.moveaxis(M_u, 1, 0)  # (t, 8N, 6)
    y_u = jnp.moveaxis(y_u, 1, 0)  # (t, 8N)
    Q, R = jnp.linalg.qr(M_u)  # (t, 8N, 6), (t, 6, 6)
    yq = jnp.einsum("tmk,tm->tk", Q, y_u)
    rest = y_u - jnp.einsum("tmk,tk->tm", Q, yq)
    return CompressedProblem(R=R, y=yq, c0=jnp.sum(rest**2), eps=problem.eps, n=n)
