# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Differentiable pieces of the design objective that need no LAPACK call.

* :func:`g_response` — ``g(jω)`` (continuous) or the matched pole-zero discrete ``g_d(e^{jωt_s})``
  in closed form (:func:`hapid.lti.matched_response`: the same discretization as
  :func:`hapid.control.discretize_compensator`, ``infinite_zeros="minus_one"``).
* :func:`smooth_sigma_max` — a smooth upper bound of the largest singular value:
  ``s_p(X) = tr((XᴴX)^p)^{1/(2p)}`` with ``p = 2^k``. Since ``tr(A^p) = Σ λ_i^p`` for the
  eigenvalues ``λ_i = σ_i²`` of ``A = XᴴX``, ``σ̄ ≤ s_p ≤ n^{1/(2p)} σ̄`` (``k = 6``: at most
  ``5^{1/128}`` = +0.11 dB for n = 5). It is a polynomial in X — smooth everywhere, also where
  singular values coincide (the isotropic loop, where ``σ̄`` itself is not differentiable) —
  and uses only matrix products (no ``eigh``/``svd`` inside the gradient: see hapid/_linalg.py
  for the XLA:CPU LAPACK deadlock). The powers are renormalized by their trace at each
  squaring, so nothing overflows.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from ..control import Compensator
from ..control._kernels import to_entries
from ..lti import matched_response


def g_response(
    g: Compensator, omega: Float[Array, " N"], ts: float | None = None
) -> Complex[Array, " N"]:
    """``g(jω)`` (``ts=None``) or the matched pole-zero ``g_d(e^{jω t_s})`` (ω in rad/s):
    :func:`hapid.lti.matched_response`."""
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if ts is None:
        return g.at_omega(omega)
    return matched_response(g, omega, ts)


def smooth_sigma_max(X: Complex[Array, "... n n"], k: int = 6) -> Float[Array, ...]:
    """``log s_p(X)`` — log of the smooth upper bound of σ̄(X) (module docstring), ``p = 2^k``."""
    return smooth_sigma_max_entries(to_entries(X), k)


def smooth_sigma_max_entries(X: Complex[Array, "n n ..."], k: int = 6) -> Float[Array, ...]:
    """:func:`smooth_sigma_max` of ``X`` stored entry-major, ``(n, n, *batch)``.

    Each matrix product is a broadcast multiply and a sum over the ``n`` axis of arrays whose
    last axes are the batch, which XLA:CPU fuses into one vectorized loop; a batched
    ``matmul`` of 5 × 5 complex matrices runs matrix by matrix (measured 1.7× slower for the
    whole objective and its gradient, 150 plants × 300 frequencies; ``benchmarks/bench_tune.py``).
    """
    A = jnp.sum(jnp.conj(X)[:, :, None] * X[:, None, :], axis=0)  # XᴴX
    t0 = jnp.maximum(jnp.real(jnp.trace(A, axis1=0, axis2=1)), 1e-300)
    B = A / t0
    acc = jnp.log(t0)
    for i in range(1, k + 1):
        B = jnp.sum(B[:, :, None] * B[None, :, :], axis=1)
        c = jnp.maximum(jnp.real(jnp.trace(B, axis1=0, axis2=1)), 1e-300)
        B = B / c
        acc = acc + jnp.log(c) / 2.0**i
    return 0.5 * acc
