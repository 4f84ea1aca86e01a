"""σ̄ of ``S = (I + L)⁻¹``, ``T`` and ``S − T`` for :func:`~hapid.control.loop_metrics`: exact
values (Jacobi on ``AᴴA``) only where cheap bounds do not decide, the first grid point above a
threshold and the grid peaks (the grid pass), the refined threshold crossing and the refined
peaks on the local loop of :mod:`._metrics_local` (the refinement pass)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .. import _config  # noqa: F401  (float64)
from . import _kernels as K
from ._lapack import lu_det_solve
from ._metrics_local import _illinois

_SECTIONS = 16  # points per multisection step (peaks)
_SECTION_STEPS = 4  # bracket × (2/17)^4 ≈ 2e-4, then
_PARABOLA_STEPS = 2  # parabolic steps on the best point


def _sigma_exact(A, kernels, unroll=False):
    """σ̄ of ``(..., n, n)`` matrices (``unroll``: for the few matrices of a refinement step)."""
    if kernels == "lapack":
        return jnp.linalg.svd(A, compute_uv=False)[..., 0]
    return K.sigma_max(K.to_entries(A), unroll=unroll)


def _det_inv(IL, kernels, unroll=False):
    if kernels == "lapack":
        eye = jnp.eye(IL.shape[-1], dtype=IL.dtype)
        return lu_det_solve(IL, jnp.broadcast_to(eye, IL.shape))
    det, S = K.det_inv(K.to_entries(IL), unroll=unroll)
    return det, K.from_entries(S)


def _fill_where(flag, fn, out, size, stop=None):
    """``out`` with ``out[i] = fn(idx)[j]`` for every ``i`` where ``flag`` (``idx`` the flagged
    indices in increasing order, ``size`` at a time: :func:`._kernels.compacted`, the work
    follows the count). ``stop(vals) → bool``: end after the first chunk where it holds
    (ascending scans)."""
    st = None if stop is None else (lambda new, valid: jnp.any(stop(new[0]) & valid))
    return K.compacted(flag, lambda idx, _: (fn(idx),), (out,), size, stop=st)[0]


def _threshold_crossing(c, i, j, thr, interp, kernels):
    """ω (rad/s) in local grid interval ``[i, j]`` of task ``c`` where σ̄(S) = ``thr``:
    Illinois on the exact (or interpolated) S over log ω, bracketed by its values at the
    interval's grid ends."""
    xi, xj = interp.lww[c, i], interp.lww[c, j]

    def f(t):
        x = xi + t * (xj - xi)
        cc = jnp.broadcast_to(c, x.shape)
        return _sigma_of_S(interp(cc, jnp.broadcast_to(i, x.shape), x), kernels) - thr

    fab = f(jnp.array([0.0, 1.0]))
    t = _illinois(f, fab[:1], fab[1:])[0]
    return jnp.exp(xi + t * (xj - xi))


def _first_above(sig_fn, lo, hi, thr, size):
    """Grid index of the lowest ω where σ̄(S) reaches ``thr`` and whether there is one;
    exact σ̄ only where the bounds ``lo``/``hi`` straddle it, up to the first sure one."""
    N = lo.shape[0]
    maybe = hi >= thr
    sure = lo >= thr
    k1 = jnp.where(jnp.any(sure), jnp.argmax(sure), N - 1)
    amb = maybe & ~sure & (jnp.arange(N) <= k1)
    above = _fill_where(amb, lambda i: sig_fn(i) >= thr, sure, size, stop=lambda v: v)
    return jnp.argmax(above), jnp.any(above)


def _sigma_of_S(L, kernels):
    n = L.shape[-1]
    IL = L + jnp.eye(n, dtype=L.dtype)
    _, S = _det_inv(IL, kernels, unroll=True)
    return _sigma_exact(S, kernels)


def _peak_grid(M_grid, size, kernels):
    """Grid maximum of σ̄(M): exact σ̄ in a window around the largest lower bound and at
    every other point whose upper bound exceeds the window's maximum: (index, value)."""
    N = M_grid.shape[0]
    lo, hi = K.sigma_bounds(K.to_entries(M_grid))
    W = min(size, N)
    start = jnp.clip(jnp.argmax(lo) - W // 2, 0, N - W)
    idx = start + jnp.arange(W)
    sig = _sigma_exact(M_grid[idx], kernels)
    j = jnp.argmax(sig)
    kpk, vpk = idx[j], sig[j]
    # points outside the window that could exceed the peak found in it: exact too
    outside = (jnp.arange(N) < start) | (jnp.arange(N) >= start + W)
    sig2 = _fill_where(
        outside & (hi > vpk), lambda i: _sigma_exact(M_grid[i], kernels), jnp.full(N, -jnp.inf), W
    )
    j2 = jnp.argmax(sig2)
    better = sig2[j2] > vpk
    return jnp.where(better, j2, kpk), jnp.where(better, sig2[j2], vpk)


def _peaks(task, kinds, interp, kernels):
    """Refined maxima of σ̄(M) (``kinds``: "T" → T = I − S, "SmT" → S − T = 2S − I) from
    their grid maxima (``task``: value ``v``, search bracket ``a``/``b`` = log ω of the
    grid neighbours, ``x0`` = log ω of the grid maximum): multisection on ``[a, b]``
    (piecewise-cubic L between the nodes), then parabolic steps, all kinds in one loop.
    Returns
    ``[(value, omega), ...]``."""
    nk = len(kinds)
    vpk, a, b = task["v"], task["a"], task["b"]

    def val(x):  # x (r·nk,): the searches in order, repeated r times
        c = jnp.arange(x.shape[0]) % nk
        Lx = interp(c, interp.interval(c, x), x)
        n = Lx.shape[-1]
        eye = jnp.eye(n, dtype=Lx.dtype)
        _, S = _det_inv(Lx + eye, kernels, unroll=True)
        M = jnp.stack(
            [eye - S[i] if kinds[i % nk] == "T" else 2.0 * S[i] - eye for i in range(x.shape[0])]
        )
        return _sigma_exact(M, kernels)

    # multisection: _SECTIONS points inside the bracket per step (one batch), the bracket
    # shrinks to the two intervals around the best: a factor (M + 1)/2 per step instead of
    # golden section's 1.618, so a few steps instead of 48 (the cost of a step is its count
    # of small sequential programs, not its handful of matrices)
    M = _SECTIONS
    u = jnp.arange(1, M + 1) / (M + 1.0)  # (M,)

    def body(_, st):
        a, b, xm, vm = st
        x = a[:, None] + u[None] * (b - a)[:, None]  # (nk, M)
        f = val(x.T.ravel()).reshape(M, nk).T  # val's order: the searches repeated
        j = jnp.argmax(f, axis=1)
        fj = jnp.take_along_axis(f, j[:, None], axis=1)[:, 0]
        xj = jnp.take_along_axis(x, j[:, None], axis=1)[:, 0]
        h = (b - a) / (M + 1.0)
        better = fj > vm
        return xj - h, xj + h, jnp.where(better, xj, xm), jnp.where(better, fj, vm)

    init = (a, b, task["x0"], jnp.full_like(vpk, -jnp.inf))
    a, b, xm, vm = jax.lax.fori_loop(0, _SECTION_STEPS, body, init)

    # then parabolic steps: the vertex of the parabola through the best point and its two
    # neighbours at ±h (σ̄ is smooth at a simple peak: the error shrinks ~cubically), h
    # shrinking with the vertex's step
    def parabola(_, st):
        xm, vm, h = st
        x3 = jnp.stack([xm - h, xm + h], axis=1)  # (nk, 2)
        f3 = val(x3.T.ravel()).reshape(2, nk).T
        fl, fr = f3[:, 0], f3[:, 1]
        den = fl - 2.0 * vm + fr
        step = jnp.where(den < 0, 0.5 * h * (fl - fr) / jnp.where(den < 0, den, -1.0), 0.0)
        step = jnp.clip(step, -h, h)
        xv = xm + step
        fv = val(xv)
        cands = jnp.stack([vm, fl, fr, fv], axis=1)
        xs = jnp.stack([xm, xm - h, xm + h, xv], axis=1)
        j = jnp.argmax(cands, axis=1)
        x_new = jnp.take_along_axis(xs, j[:, None], axis=1)[:, 0]
        f_new = jnp.take_along_axis(cands, j[:, None], axis=1)[:, 0]
        return x_new, f_new, jnp.maximum(jnp.abs(step), 1e-3 * h)

    xm, vm, _ = jax.lax.fori_loop(0, _PARABOLA_STEPS, parabola, (xm, vm, 0.25 * (b - a)))
    better = vm > vpk
    v = jnp.where(better, vm, vpk)
    w = jnp.where(better, jnp.exp(xm), jnp.exp(task["x0"]))
    return [(v[i], w[i]) for i in range(nk)]
