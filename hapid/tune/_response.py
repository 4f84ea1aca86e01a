# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Differentiable pieces of the design objective that need no LAPACK call.

* :func:`g_response` — ``g(jω)`` (continuous) or the matched pole-zero discrete ``g_d(e^{jωt_s})``
  in closed form, section by section (the same discretization as
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


def _cosh_sqrt(u):
    """``cosh(√u)`` for real u of either sign, smooth at 0 (entire function of u)."""
    small = jnp.abs(u) < 1e-4
    us = jnp.where(small, 1.0, u)
    pos = jnp.cosh(jnp.sqrt(jnp.where(us > 0, us, 1.0)))
    neg = jnp.cos(jnp.sqrt(jnp.where(us < 0, -us, 1.0)))
    series = 1.0 + u / 2.0 + u * u / 24.0
    return jnp.where(small, series, jnp.where(u > 0, pos, neg))


def _pair(zeta, w, ts):
    """``q² + c1 q + c2`` with roots ``e^{r t_s}``, ``r = −ζω ± ω√(ζ²−1)``."""
    c1 = -2.0 * jnp.exp(-zeta * w * ts) * _cosh_sqrt((w * ts) ** 2 * (zeta**2 - 1.0))
    c2 = jnp.exp(-2.0 * zeta * w * ts)
    return c1, c2


def g_response(
    g: Compensator, omega: Float[Array, " N"], ts: float | None = None
) -> Complex[Array, " N"]:
    """``g(jω)`` (``ts=None``) or the matched pole-zero ``g_d(e^{jω t_s})`` (ω in rad/s)."""
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if ts is None:
        return g.at_omega(omega)
    q = jnp.exp(1j * omega * ts)[:, None]
    z, p = g.lag_zeros, g.lag_poles
    a, b = jnp.exp(-z * ts), jnp.exp(-p * ts)
    K = (z / p) * (1.0 - b) / (1.0 - a)
    lag = jnp.prod(K * (q - a) / (q - b), axis=-1)
    w = g.notch_omega
    n1, n2 = _pair(g.notch_zeta_num, w, ts)
    d1, d2 = _pair(g.notch_zeta_den, w, ts)
    Kn = (1.0 + d1 + d2) / (1.0 + n1 + n2)
    notch = jnp.prod(Kn * (q * q + n1 * q + n2) / (q * q + d1 * q + d2), axis=-1)
    bl = jnp.exp(-g.lowpass * ts)
    lp = jnp.prod((1.0 - bl) / 2.0 * (q + 1.0) / (q - bl), axis=-1)
    return g.k * lag * notch * lp


def smooth_sigma_max(X: Complex[Array, "... n n"], k: int = 6) -> Float[Array, ...]:
    """``log s_p(X)`` — log of the smooth upper bound of σ̄(X) (module docstring), ``p = 2^k``."""
    A = jnp.swapaxes(jnp.conj(X), -1, -2) @ X
    t0 = jnp.real(jnp.trace(A, axis1=-2, axis2=-1))
    t0 = jnp.maximum(t0, 1e-300)
    B = A / t0[..., None, None]
    acc = jnp.log(t0)
    for i in range(1, k + 1):
        B = B @ B
        c = jnp.maximum(jnp.real(jnp.trace(B, axis1=-2, axis2=-1)), 1e-300)
        B = B / c[..., None, None]
        acc = acc + jnp.log(c) / 2.0**i
    return 0.5 * acc
