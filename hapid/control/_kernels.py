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
* :func:`eigvals` — all eigenvalues (Householder → Hessenberg, Wilkinson-shifted QR with
  deflation, ``n ≤ MAX_EIG_N`` unrolled; LAPACK's ``eigvals`` above).
* :func:`pair_optimal` — the optimal-permutation pairing of eigenvalues between two
  frequencies (the reference tracker's rule), by dynamic programming over subsets.

Entry-major layout: ``to_entries`` / ``from_entries`` move ``(..., n, n)`` ↔ ``(n, n, ...)``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from ._lapack import lu_det_solve

MAX_UNROLLED_N = 12
MAX_EIG_N = 6  # unrolled QR compiles in ~25 s at n = 6, minutes at n = 8
_EIG_CAP = 2  # QR steps per deflation stage for the whole batch; the rest in blocks
_EIG_BLOCK = 128
_JACOBI_SWEEPS = {2: 3, 3: 5, 4: 6, 5: 6, 6: 7}
_ULP = float(np.finfo(np.float64).eps)
_SAFMIN = float(np.finfo(np.float64).tiny)


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


def det_inv_screened(A, tau: float = 0.5):
    """:func:`det_inv` for a large batch ``A (n, n, B)``: Gauss–Jordan without row exchanges
    (every step a few fused elementwise ops), checked per matrix — each pivot must be at
    least ``tau`` times the largest entry below it in its column (threshold pivoting: the
    growth factor stays below ``(1 + 1/tau)^(n − 1)``) — and the matrices that fail redone
    with partial pivoting (:func:`det_inv`), gathered in blocks. Same results as
    :func:`det_inv` to rounding."""
    n = A.shape[0]
    if n > MAX_UNROLLED_N or A.ndim != 3:
        return det_inv(A, unroll=True)
    B = A.shape[2]
    M = [[A[i, j] for j in range(n)] for i in range(n)]
    one, zero = jnp.ones((B,), A.dtype), jnp.zeros((B,), A.dtype)
    M = [M[i] + [one if i == j else zero for j in range(n)] for i in range(n)]
    det = one
    ok = jnp.ones((B,), dtype=bool)
    for k in range(n):
        piv = M[k][k]
        below = [_cabs1(M[i][k]) for i in range(k + 1, n)]
        if below:
            ok = ok & (_cabs1(piv) >= tau * functools.reduce(jnp.maximum, below))
        ok = ok & (piv != 0)
        det = det * piv
        inv = 1.0 / piv
        rk = [M[k][j] * inv for j in range(2 * n)]
        for i in range(n):
            if i != k:
                f = M[i][k]
                M[i] = [M[i][j] - f * rk[j] for j in range(2 * n)]
        M[k] = rk
    flat = [A[i, j] for i in range(n) for j in range(n)]
    S = [M[i][n + j] for i in range(n) for j in range(n)]

    def redo(_, f):
        Ab = jnp.stack(f[: n * n]).reshape(n, n, -1)
        d, Si = det_inv(Ab, unroll=True)
        return tuple(f[: n * n]) + (d,) + tuple(Si.reshape(n * n, -1))

    out = compacted(~ok, redo, tuple(flat) + (det,) + tuple(S), size=256)
    return out[n * n], jnp.stack(out[n * n + 1 :]).reshape(n, n, B)


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


def hermitian_eigvals(H, sweeps: int | None = None, unroll: bool = False):
    """Eigenvalues ``(n, ...)`` (unsorted, real) of Hermitian ``H (n, n, ...)`` by cyclic
    Jacobi (``sweeps`` default by ``n``; quadratic convergence, rounding-level results).
    ``unroll``: every sweep inlined too (else one ``fori_loop`` step per sweep)."""
    n = H.shape[0]
    if sweeps is None:
        sweeps = _JACOBI_SWEEPS.get(n, 8)
    pairs = np.array([(p, q) for p in range(n - 1) for q in range(p + 1, n)], dtype=np.int32)
    if unroll:
        for _ in range(sweeps):
            for p, q in pairs:
                H = _jacobi_rotate(H, int(p), int(q))
    elif len(pairs):
        # one loop step per sweep, its rotations inlined (static indices): ``sweeps``
        # sequential steps instead of ``sweeps·n(n−1)/2`` (each step a fused elementwise body)

        def sweep(_, h):
            for p, q in pairs:
                h = _jacobi_rotate(h, int(p), int(q))
            return h

        H = jax.lax.fori_loop(0, sweeps, sweep, H)
    return jnp.real(jnp.stack([H[i, i] for i in range(n)]))


def gram(A):
    """``Aᴴ A`` for entry-major ``A``."""
    return jnp.einsum("ki...,kj...->ij...", jnp.conj(A), A)


def sigma_max(A, sweeps: int | None = None, unroll: bool = False):
    """σ̄(A) for ``A (n, n, ...)``: the largest eigenvalue of ``AᴴA`` by Jacobi, square-rooted."""
    ev = hermitian_eigvals(gram(A), sweeps, unroll)
    return jnp.sqrt(jnp.maximum(jnp.max(ev, axis=0), 0.0))


def eig_newton(A, z0, iters: int = 6, active=None):
    """The eigenvalue of ``A (n, n, ...)`` nearest the guess ``z0 (...)`` (Newton on
    ``det(A − zI)``; quadratic for a simple eigenvalue once close). Stops when every step is
    at rounding level (``|Δz| ≤ 4ε·max(|z|, ‖A‖_F)``: an eigenvalue is defined to ~ε‖A‖
    absolutely, so a small one is not iterated on rounding noise), at most ``iters`` steps.
    ``active`` (bool ``(...)``, optional): only these decide when to stop (the others are
    iterated along but their results are not meant to be used). A matrix stops changing
    once its own step is at rounding level, so its result does not depend on the batch."""
    n = A.shape[0]
    eye = jnp.eye(n, dtype=A.dtype).reshape((n, n) + (1,) * (A.ndim - 2))
    floor = 4.0 * _ULP * jnp.sqrt(fro2(A))

    def body(c):
        it, z, stopped = c
        _, Ai = det_inv(A - eye * z, unroll=True)
        tr = sum(Ai[i, i] for i in range(n))
        step = jnp.where(jnp.isfinite(tr) & (tr != 0), 1.0 / jnp.where(tr != 0, tr, 1.0), 0.0)
        small = jnp.abs(step) <= jnp.maximum(4.0 * _ULP * jnp.abs(z), floor)
        # a matrix that has converged keeps its value: the result of each does not depend
        # on what else is in the batch
        z = jnp.where(stopped, z, z + step)
        return it + 1, z, stopped | small | ~jnp.isfinite(step)

    def cond(c):
        busy = ~c[2] if active is None else ~c[2] & active
        return (c[0] < iters) & jnp.any(busy)

    stopped = jnp.zeros(jnp.shape(z0), dtype=bool)
    return jax.lax.while_loop(cond, body, (jnp.asarray(0), z0, stopped))[1]


# --------------------------------------------------------------------------------------
# eigenvalues of small complex matrices: Hessenberg reduction + shifted QR, batch last


def _rows(A):
    """``(n, n, ...)`` → list of lists of ``(...)`` entries (Python-unrolled algebra)."""
    n = A.shape[0]
    return [[A[i, j] for j in range(n)] for i in range(n)]


def hessenberg(A):
    """Upper Hessenberg ``H`` unitarily similar to ``A (n, n, ...)`` complex (Householder
    reflections, unrolled; returns the entry lists of :func:`_rows`)."""
    n = A.shape[0]
    H = _rows(A)
    for k in range(n - 2):
        x = [H[i][k] for i in range(k + 1, n)]
        xn = jnp.sqrt(sum(jnp.real(v) ** 2 + jnp.imag(v) ** 2 for v in x))
        ax = jnp.abs(x[0])
        ph = jnp.where(ax > 0, x[0] / jnp.where(ax > 0, ax, 1.0), 1.0)
        v = [x[0] + ph * xn] + x[1:]
        vn2 = sum(jnp.real(u) ** 2 + jnp.imag(u) ** 2 for u in v)
        beta = jnp.where(vn2 > 0, 2.0 / jnp.where(vn2 > 0, vn2, 1.0), 0.0)
        rr = range(k + 1, n)
        # rows k+1..n−1: H ← (I − β v vᴴ) H
        for j in range(k, n):
            w = beta * sum(jnp.conj(v[a]) * H[i][j] for a, i in enumerate(rr))
            for a, i in enumerate(rr):
                H[i][j] = H[i][j] - v[a] * w
        # columns k+1..n−1: H ← H (I − β v vᴴ)
        for i in range(n):
            w = beta * sum(H[i][j] * v[a] for a, j in enumerate(rr))
            for a, j in enumerate(rr):
                H[i][j] = H[i][j] - w * jnp.conj(v[a])
        for i in range(k + 2, n):
            H[i][k] = jnp.zeros_like(H[i][k])
    return H


def _wilkinson(a, b, c, d):
    """Eigenvalue of ``[[a, b], [c, d]]`` nearest ``d``."""
    t = 0.5 * (a + d)
    disc = jnp.sqrt((0.5 * (a - d)) ** 2 + b * c)
    e1, e2 = t + disc, t - disc
    return jnp.where(_cabs1(e1 - d) <= _cabs1(e2 - d), e1, e2)


def _qr_step(H, mu):
    """One explicit shifted QR step ``H − μI = QR → RQ + μI`` on the Hessenberg entry lists
    (Givens rotations with real cosines)."""
    m = len(H)
    H = [row[:] for row in H]
    for i in range(m):
        H[i][i] = H[i][i] - mu
    rots = []
    for k in range(m - 1):
        a, b = H[k][k], H[k + 1][k]
        aa = jnp.abs(a)
        r = jnp.sqrt(aa * aa + jnp.real(b) ** 2 + jnp.imag(b) ** 2)
        ok = r > 0
        rs = jnp.where(ok, r, 1.0)
        ph = jnp.where(aa > 0, a / jnp.where(aa > 0, aa, 1.0), 1.0)
        c = jnp.where(ok, aa / rs, 1.0)
        s = jnp.where(ok, ph * jnp.conj(b) / rs, 0.0)
        rots.append((c, s))
        for j in range(k, m):
            hk, hk1 = H[k][j], H[k + 1][j]
            H[k][j] = c * hk + s * hk1
            H[k + 1][j] = c * hk1 - jnp.conj(s) * hk
        H[k + 1][k] = jnp.zeros_like(H[k + 1][k])
    for k, (c, s) in enumerate(rots):
        for i in range(min(k + 2, m - 1) + 1):
            hk, hk1 = H[i][k], H[i][k + 1]
            H[i][k] = c * hk + jnp.conj(s) * hk1
            H[i][k + 1] = c * hk1 - s * hk
    for i in range(m):
        H[i][i] = H[i][i] + mu
    return H


def eigvals(A, max_iter: int = 40):
    """Eigenvalues ``(n, ...)`` of complex ``A (n, n, ...)`` (batch last), no LAPACK.

    Householder reduction to Hessenberg form, then single-shift (Wilkinson) QR on the active
    leading block, deflating one eigenvalue at the bottom when its subdiagonal entry falls
    below ``ulp·(|h_{m−1,m−1}| + |h_{m,m}|)`` (LAPACK ``zlahqr``'s test), with an
    exceptional shift every 10 iterations. Each deflation stage runs ``_EIG_CAP`` steps on
    the whole batch, then continues only the matrices not yet deflated, gathered in blocks
    (at most ``max_iter`` steps each; a matrix's steps do not depend on the batch). Backward
    stable like LAPACK's ``zgeev``; the order is the deflation order (no sorting).
    """
    n = A.shape[0]
    A = jnp.asarray(A, dtype=jnp.complex128)
    if n == 1:
        return A[0]
    if n > MAX_EIG_N:
        return to_entries(jnp.linalg.eigvals(from_entries(A))[..., None])[:, 0]
    bshape = A.shape[2:]
    A = A.reshape(n, n, -1)  # one flat batch (B,)
    H = hessenberg(A)
    out = [None] * n
    for m in range(n, 1, -1):
        Hm = [row[:m] for row in H[:m]]
        flat = [x for row in Hm for x in row]

        def unflat(f, m=m):
            return [list(f[i * m : (i + 1) * m]) for i in range(m)]

        def done_of(Hm, m=m):
            sub = _cabs1(Hm[m - 1][m - 2])
            tst = _cabs1(Hm[m - 1][m - 1]) + _cabs1(Hm[m - 2][m - 2])
            return (sub <= _ULP * tst) | (sub <= _SAFMIN) | ~jnp.isfinite(sub)

        def qr(it0, f, stop, done_of=done_of, unflat=unflat, m=m):
            """QR steps from iteration ``it0`` until every matrix of ``f`` has deflated or
            the iteration count reaches ``stop``; a deflated matrix keeps its values."""

            def cond(c):
                it, f = c
                return (it < stop) & ~jnp.all(done_of(unflat(f)))

            def body(c):
                it, f = c
                Hm = unflat(f)
                done = done_of(Hm)
                a, b = Hm[m - 2][m - 2], Hm[m - 2][m - 1]
                mu = _wilkinson(a, b, Hm[m - 1][m - 2], Hm[m - 1][m - 1])
                exc = Hm[m - 1][m - 1] + 0.75 * jnp.abs(jnp.real(Hm[m - 1][m - 2]))
                mu = jnp.where((it % 10) == 9, exc, mu)
                new = _qr_step(Hm, mu)
                nf = [x for row in new for x in row]
                return it + 1, tuple(jnp.where(done, o, x) for o, x in zip(f, nf, strict=True))

            return jax.lax.while_loop(cond, body, (jnp.asarray(it0), tuple(f)))[1]

        # every matrix gets _EIG_CAP steps together; the few that need more (the batch's
        # slowest set the step count of a shared loop) continue in blocks of _EIG_BLOCK,
        # on the same shift schedule, so each matrix's result is the same either way
        flat = qr(0, flat, min(_EIG_CAP, max_iter))
        flat = compacted(~done_of(unflat(flat)), lambda _, f: qr(_EIG_CAP, f, max_iter), flat)
        Hm = unflat(flat)
        out[m - 1] = Hm[m - 1][m - 1]
        H = [row[: m - 1] for row in Hm[: m - 1]]
    out[0] = H[0][0]
    return jnp.stack(out).reshape((n,) + bshape)


def compacted(flag, fn, arrays, size=None, stop=None):
    """``arrays`` (a tuple of arrays sharing the leading axis ``(B, ...)``) with
    ``fn(idx, sub) → sub'`` applied to the entries where ``flag (B,)``: the flagged entries
    are gathered ``size`` at a time (default ``_EIG_BLOCK``; ``idx`` their indices in
    increasing order, ``sub`` the gathered arrays) in a ``while_loop`` and scattered back —
    the work follows the count of flagged entries, not the batch (under ``vmap`` the loop runs
    to the largest count of the batch). ``stop(sub', valid) → bool``: end after the first
    block where it holds (ascending scans; ``valid`` masks the block's padding)."""
    B = flag.shape[0]
    size = min(size or _EIG_BLOCK, B)
    idx = jnp.nonzero(flag, size=B, fill_value=B)[0]
    idx = jnp.concatenate([idx, jnp.full(size, B, dtype=idx.dtype)])
    count = jnp.sum(flag)

    def body(c):
        j, f, _ = c
        sl = jax.lax.dynamic_slice(idx, (j * size,), (size,))
        g = jnp.minimum(sl, B - 1)
        sub = fn(g, tuple(x[g] for x in f))
        found = jnp.asarray(False) if stop is None else stop(sub, sl < B)
        f = tuple(x.at[sl].set(v.astype(x.dtype), mode="drop") for x, v in zip(f, sub, strict=True))
        return j + 1, f, found

    def cond(c):
        return (c[0] * size < count) & ~c[2]

    return jax.lax.while_loop(cond, body, (jnp.asarray(0), tuple(arrays), jnp.asarray(False)))[1]


def _pair_traceback(tab, b):
    """``b (n, ...)`` ordered by the optimal-permutation DP's choice table ``tab (2ⁿ, ...)``
    (row ``S``: the ``j`` chosen for the last row of the subset ``S``)."""
    n = b.shape[0]
    S = jnp.full(b.shape[1:], (1 << n) - 1, dtype=jnp.int32)
    sig = [None] * n
    for i in range(n - 1, -1, -1):
        j = jnp.take_along_axis(tab, S[None], axis=0)[0]
        sig[i] = j
        S = S - jnp.left_shift(1, j)
    return jnp.take_along_axis(b, jnp.stack(sig), axis=0)


def pair_optimal(a, b):
    """Order eigenvalues ``b (n, ...)`` to continue ``a (n, ...)``: the permutation σ that
    minimizes ``Σ|a_i − b_σ(i)|²`` (the reference tracker's choice), by dynamic programming
    over subsets (``n·2ⁿ⁻¹`` candidate sums instead of ``n·n!``).

    ``f(S) = min_{j ∈ S} f(S ∖ j) + |a_{|S|−1} − b_j|²``, one level of subsets of equal size
    at a time: the candidates of a level stacked ``(subsets, |S|, ...)`` and reduced with
    ``min`` / ``argmin`` (a reduction is where XLA stores a level instead of recomputing it
    in every consumer, which a chain of selects does not give); ties go to the smallest
    ``j`` (``argmin``'s first minimum). The traceback reads the choices from a ``(2ⁿ, ...)``
    table."""
    n = a.shape[0]
    bshape = a.shape[1:]
    d = jnp.abs(a[:, None] - b[None, :]) ** 2  # (n, n, ...): d[i, j]
    F = jnp.zeros((1,) + bshape, dtype=jnp.float64)
    row = {0: 0}
    order, levels = [0], [jnp.zeros((1,) + bshape, dtype=jnp.int32)]
    ex = (slice(None), slice(None)) + (None,) * len(bshape)
    for k in range(1, n + 1):
        level = [S for S in range(1, 1 << n) if bin(S).count("1") == k]
        js = np.array([[j for j in range(n) if S >> j & 1] for S in level])  # (L, k)
        prev = np.array(
            [[row[S ^ (1 << j)] for j in js_S] for S, js_S in zip(level, js, strict=True)]
        )
        cand = F[prev] + d[k - 1][js]  # (L, k, ...)
        F = jnp.min(cand, axis=1)
        p = jnp.argmin(cand, axis=1).astype(jnp.int32)
        jsel = jnp.broadcast_to(jnp.asarray(js, dtype=jnp.int32)[ex], cand.shape)
        levels.append(jnp.take_along_axis(jsel, p[:, None], axis=1)[:, 0])
        row = {S: r for r, S in enumerate(level)}
        order += level
    tab = jnp.concatenate(levels)[np.argsort(order)]  # (2ⁿ, ...): row S = the choice at S
    return _pair_traceback(tab, b)
