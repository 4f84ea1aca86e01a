"""Linear-algebra helpers that are safe inside large jitted programs on XLA:CPU.

With jaxlib 0.10.2 a batched LAPACK SVD (``gesdd``) that XLA schedules concurrently with a
batched LU (``getrf``: ``solve``, ``inv``, ``det``) in the same program deadlocks (all threads
idle, measured: ``svd + solve`` hangs every time on this 2-core machine, ``svd``, ``solve``,
``eigh + solve`` alone never). hapid computes singular values inside JAX programs from the
Hermitian eigenvalues of ``AᴴA`` instead (``eigh`` does not deadlock with LU). The relative
error of the smallest singular value is ≈ ε·(σ̄/σ̲)², i.e. 1e-11 at a 50 dB span and 1e-4 at
120 dB — ample for dB plots and band edges; use numpy's SVD at the edges when a tiny
singular value itself matters.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float


def svdvals(A):
    """Singular values of ``(..., m, n)`` matrices, descending, ``(..., min(m, n))``."""
    Ah = jnp.swapaxes(jnp.conj(A), -1, -2)
    G = Ah @ A if A.shape[-1] <= A.shape[-2] else A @ Ah
    ev = jnp.linalg.eigvalsh(G)
    return jnp.sqrt(jnp.clip(ev[..., ::-1], 0.0, None))


def pinv_psd(F: Float[Array, "p p"]) -> Float[Array, "p p"]:
    """Pseudo-inverse of a symmetric PSD matrix (an information ``JᵀJ``): eigenvalues below
    ``1e-12`` × the largest (unidentified directions) get variance 0, not 1/0."""
    lam, V = jnp.linalg.eigh(0.5 * (F + F.T))
    keep = lam > 1e-12 * jnp.max(lam)
    inv = jnp.where(keep, 1.0 / jnp.where(keep, lam, 1.0), 0.0)
    return (V * inv) @ V.T
