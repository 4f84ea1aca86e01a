"""Small-matrix kernels as plain XLA ops, batch on the LAST axes (no LAPACK custom calls).

For the loop analysis hapid works on stacks of small complex matrices (n = 2..12, one per
frequency and per plant). LAPACK custom calls run those matrix by matrix (and two batched
LAPACK kernels scheduled concurrently deadlock XLA:CPU with jaxlib 0.10.2, see
:mod:`._lapack`). The kernels here keep the matrix dimensions in front — an array
``(n, n, *batch)`` — and unroll the elimination for the given ``n`` in Python, so every
operation is an elementwise op on a contiguous batch vector: they vectorize across the
batch, run the same on GPU and cannot meet the LAPACK hang.

* :func:`det_inv` — determinant and inverse, Gauss–Jordan with partial pivoting (pivot by
  ``|Re| + |Im|``, LAPACK's ``izamax`` choice), ``n ≤ 12`` unrolled, LAPACK above.
* :func:`sigma_bounds` — cheap two-sided bounds of σ̄: ``‖A‖_F/√n ≤ σ̄ ≤ ‖A‖_F`` sharpened
  with the trace (``|tr A|/n ≤ ρ(A) ≤ σ̄ ≤ |c| + ‖A − cI‖_F``, ``c = tr A/n``), which is
  tight for the near-scalar matrices of a well-modelled loop.
* :func:`sigma_max` — σ̄ to rounding: cyclic complex Jacobi on ``AᴴA`` (a few sweeps);
  meant for the few matrices where the bounds do not decide.
* :func:`eig_disc` — a disc (centre ``tr A/n``, radius ``‖A − cI‖_F``) containing every
  eigenvalue of ``A`` (Schur's inequality).
* :func:`eig_newton` — the eigenvalue of ``A`` nearest a guess, by Newton on ``det(A − zI)``
  (``z ← z + 1/tr((A − zI)⁻¹)``).

Entry-major layout: ``to_entries`` / ``from_entries`` move ``(..., n, n)`` ↔ ``(n, n, ...)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)

MAX_UNROLLED_N = 12
_JACOBI_SWEEPS = {2: 3, 3: 5, 4: 6, 5: 6, 6: 7}


def to_entries(A):
    """``(..., n, n)`` → ``(n, n, ...)`` (batch last)."""
    return jnp.moveaxis(A, (-2, -1), (0, 1))


def from_entries(A):
    """``(n, n, ...)`` → ``(..., n, n)``."""
    return jnp.moveaxis(A, (0, 1), (-2, -1))


def _cabs1(z):
    return jnp.abs(jnp.real(z)) + jnp.abs(jnp.imag(z))


def det_inv(A, unroll: bool = False):
    """Determinant ``(...)`` and inverse ``(n, n, ...)`` of ``A (n, n, ...)`` complex.

    Gauss–Jordan with partial pivoting on the augmented ``[A | I]``, one rank-1 update per
    column (``n`` steps unrolled, each a handful of ops on the whole ``(n, 2n, ...)``
    block); a singular matrix gives ``det = 0`` and a non-finite inverse (as LAPACK).
    Above ``MAX_UNROLLED_N``, LAPACK's LU.
    """
    n = A.shape[0]
    if n > MAX_UNROLLED_N:
        from ._lapack import lu_det_solve

        Am = from_entries(A)
        eye = jnp.eye(n, dtype=Am.dtype)
        det, X = lu_det_solve(Am, jnp.broadcast_to(eye, Am.shape))
        return det, to_entries(X)
    bshape = A.shape[2:]
    ex = (slice(None),) + (None,) * len(bshape)
    eye = jnp.broadcast_to(jnp.eye(n, dtype=A.dtype)[(...,) + (None,) * len(bshape)], A.shape)
    M = jnp.concatenate([A, eye], axis=1)  # (n, 2n, ...)
    rows = jnp.arange(n)[ex]
    det = jnp.ones(bshape, dtype=A.dtype)

    def step(k, carry):
        M, det = carry
        col = jax.lax.dynamic_index_in_dim(M, k, axis=1, keepdims=False)  # (n, ...)
        mag = jnp.where(rows >= k, _cabs1(col), -1.0)
        p = jnp.argmax(mag, axis=0)  # first maximum, as izamax
        onehot = (rows == p[None]).astype(M.dtype)  # (n, ...)
        row_p = jnp.sum(onehot[:, None] * M, axis=0)  # (2n, ...)
        row_k = jax.lax.dynamic_index_in_dim(M, k, axis=0, keepdims=False)
        M = M + onehot[:, None] * (row_k - row_p)[None]
        det = jnp.where(p != k, -det, det)
        piv = jax.lax.dynamic_index_in_dim(row_p, k, axis=0, keepdims=False)
        det = det * piv
        row = row_p * (1.0 / piv)[None]
        f = jnp.where(rows == k, 0.0, jax.lax.dynamic_index_in_dim(M, k, axis=1, keepdims=False))
        M = M - f[:, None] * row[None]
        M = jax.lax.dynamic_update_index_in_dim(M, row, k, axis=0)
        return M, det

    if unroll:
        for k in range(n):
            M, det = step(k, (M, det))
    else:
        M, det = jax.lax.fori_loop(0, n, step, (M, det))
    return det, M[:, n:]


def matmul(A, B):
    """``A @ B`` for entry-major ``(n, k, ...)`` and ``(k, m, ...)``."""
    return jnp.einsum("ik...,kj...->ij...", A, B)


def fro2(A):
    """Squared Frobenius norm over the two leading (matrix) axes."""
    return jnp.sum(jnp.real(A) ** 2 + jnp.imag(A) ** 2, axis=(0, 1))


def eig_disc(A):
    """``(c, r)``: every eigenvalue λ of ``A (n, n, ...)`` has ``|λ − c| ≤ r``
    (``c = tr A/n``, ``r = ‖A − cI‖_F``, Schur's inequality)."""
    n = A.shape[0]
    c = sum(A[i, i] for i in range(n)) / n
    off = fro2(A) - n * jnp.abs(c) ** 2  # ‖A − cI‖_F² = ‖A‖_F² − n|c|²
    return c, jnp.sqrt(jnp.maximum(off, 0.0))


def sigma_bounds(A):
    """``(lo, hi)`` with ``lo ≤ σ̄(A) ≤ hi`` for ``A (n, n, ...)`` (module docstring)."""
    n = A.shape[0]
    f = jnp.sqrt(fro2(A))
    c, r = eig_disc(A)
    lo = jnp.maximum(f / np.sqrt(n), jnp.abs(c))
    hi = jnp.minimum(f, jnp.abs(c) + r)
    return lo, jnp.maximum(hi, lo)


def _jacobi_rotate(h, p, q):
    """One complex Jacobi rotation of Hermitian ``h (n, n, ...)`` zeroing ``h[p, q]``
    (``p``, ``q`` traced indices: one small program for every pair)."""
    b = h[p, q]
    beta = jnp.abs(b)
    dd = jnp.real(h[q, q]) - jnp.real(h[p, p])
    den = jnp.abs(dd) + jnp.sqrt(dd * dd + 4.0 * beta * beta)
    sgn = jnp.where(dd >= 0, 1.0, -1.0)
    t = jnp.where(den > 0, sgn * 2.0 * beta / jnp.where(den > 0, den, 1.0), 0.0)
    c = 1.0 / jnp.sqrt(1.0 + t * t)
    s = t * c
    e = jnp.where(beta > 0, jnp.conj(b) / jnp.where(beta > 0, beta, 1.0), 1.0)  # e^{−iφ}
    # G = [[c, s], [−s e, c e]]; h ← Gᴴ h G on columns, then rows p, q
    cp, cq = h[:, p], h[:, q]
    h = h.at[:, p].set(cp * c - cq * (s * e)).at[:, q].set(cp * s + cq * (c * e))
    rp, rq = h[p], h[q]
    h = h.at[p].set(rp * c - rq * jnp.conj(s * e)).at[q].set(rp * s + rq * jnp.conj(c * e))
    return h.at[p, q].set(0.0).at[q, p].set(0.0)


def hermitian_eigvals(H, sweeps: int | None = None):
    """Eigenvalues ``(n, ...)`` (unsorted, real) of Hermitian ``H (n, n, ...)`` by cyclic
    Jacobi (``sweeps`` default by ``n``; quadratic convergence, rounding-level results)."""
    n = H.shape[0]
    if sweeps is None:
        sweeps = _JACOBI_SWEEPS.get(n, 8)
    pairs = np.array([(p, q) for p in range(n - 1) for q in range(p + 1, n)], dtype=np.int32)
    if len(pairs):
        P, Q = jnp.asarray(pairs[:, 0]), jnp.asarray(pairs[:, 1])
        m = len(pairs)
        H = jax.lax.fori_loop(0, sweeps * m, lambda i, h: _jacobi_rotate(h, P[i % m], Q[i % m]), H)
    return jnp.real(jnp.stack([H[i, i] for i in range(n)]))


def gram(A):
    """``Aᴴ A`` for entry-major ``A``."""
    return jnp.einsum("ki...,kj...->ij...", jnp.conj(A), A)


def sigma_max(A, sweeps: int | None = None):
    """σ̄(A) for ``A (n, n, ...)``: the largest eigenvalue of ``AᴴA`` by Jacobi, square-rooted."""
    ev = hermitian_eigvals(gram(A), sweeps)
    return jnp.sqrt(jnp.maximum(jnp.max(ev, axis=0), 0.0))


def eig_newton(A, z0, iters: int = 6):
    """The eigenvalue of ``A (n, n, ...)`` nearest the guess ``z0 (...)`` (Newton on
    ``det(A − zI)``; quadratic for a simple eigenvalue once close)."""
    n = A.shape[0]
    eye = jnp.eye(n, dtype=A.dtype).reshape((n, n) + (1,) * (A.ndim - 2))

    def body(_, z):
        _, Ai = det_inv(A - eye * z)
        tr = sum(Ai[i, i] for i in range(n))
        step = jnp.where(jnp.isfinite(tr) & (tr != 0), 1.0 / jnp.where(tr != 0, tr, 1.0), 0.0)
        return z + step

    return jax.lax.fori_loop(0, iters, body, z0)
