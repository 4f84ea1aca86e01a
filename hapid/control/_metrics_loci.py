"""The characteristic loci for :func:`~hapid.control.loop_metrics`: the screen of the grid
intervals where the loci rules may act (:func:`_loci_screen`), the loci paired across those
intervals, the margin candidates (crossings of ``|λ| = 1`` and of the negative real axis) and
their refinement on the local loop of :mod:`._metrics_local`.

``SCREEN_LOCI`` (read at trace time): ``False`` computes the eigenvalues at every frequency
(for benchmarks)."""

from __future__ import annotations

import importlib

import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from . import _kernels as K
from ._margins import _DB, _pm_deg, gain_crossing, phase_crossing
from ._metrics_local import _ROOT_ITERS, _illinois_done, _illinois_init, _illinois_state, _Local
from ._nyquist import _MAX_PERMUTATION_N, _match_greedy

_N_REFINE = 4
_STAGE1 = 8  # Illinois steps every loci candidate gets; the rest continue in blocks
_BLOCK = 64
# a value being batched by vmap (private to JAX; if it moves, the cond runs under vmap too)
_BATCHED = getattr(importlib.import_module("jax._src.interpreters.batching"), "BatchTracer", ())
SCREEN_LOCI = True  # False: eigenvalues at every frequency (for benchmarks: read at trace time)


def _loci_screen(Le, spec):
    """``(N − 1,)`` bool for ``Le (n, n, N)`` (entry-major): the grid intervals where the loci
    rules may act — an interval left out provably has no unresolved locus step and (with
    ``spec.margins``) no margin candidate, whatever eigenvalues the kernel returns and
    however they are paired.

    Every eigenvalue of ``L(jω_k)`` lies in the disc of centre ``c_k = tr L/n`` and radius
    ``r_k = ‖L − c_k I‖_F`` (Schur), inflated by ``1e-10 ‖L‖_F`` so that it also holds the
    computed ones (the QR kernel is backward stable: an exact eigenvalue of ``L + E``,
    ``‖E‖ ~ n² ε ‖L‖``); both ends of an interval lie in one disc ``(m, R)``. The interval
    is left out when that disc (i) sees ``−1`` under a half-angle below half the allowed
    phase step (every paired ``1 + λ`` then turns less than ``max_phase_step``), and with
    margins (ii) lies inside or outside the unit circle (no ``|λ|`` crosses 1) and (iii) does
    not meet the negative real axis (a sign change of ``Im λ`` there is interpolated on a
    chord inside the disc, at ``Re > 0``). NaN anywhere: kept. Where the model is right the
    loci cluster about ``g`` and most intervals are left out (default loop draws of cu5: 66 %);
    where they spread about their mean few are (parameter draws of cu5: 7 %)."""
    n = Le.shape[0]
    c = sum(Le[i, i] for i in range(n)) / n
    r2 = sum(
        jnp.abs(Le[i, j] - c) ** 2 if i == j else jnp.abs(Le[i, j]) ** 2
        for i in range(n)
        for j in range(n)
    )
    r = jnp.sqrt(r2)
    r = r + 1e-10 * (np.sqrt(n) * jnp.abs(c) + r)  # ‖L‖_F ≤ √n|c| + r
    m = 0.5 * (c[1:] + c[:-1])
    R = 0.5 * jnp.abs(c[1:] - c[:-1]) + jnp.maximum(r[1:], r[:-1])
    half = min(0.5 * spec.max_phase_step, 0.5 * np.pi)
    left_out = R < jnp.abs(1.0 + m) * np.sin(half)
    if spec.margins:
        am = jnp.abs(m)
        chord = jnp.sqrt(jnp.maximum(R**2 - jnp.imag(m) ** 2, 0.0))
        off_axis = (jnp.abs(jnp.imag(m)) > R) | (jnp.real(m) - chord > 0)
        left_out = left_out & ((am - R > 1.0) | (am + R < 1.0)) & off_axis
    return ~left_out


def _loci_pairs(L, spec, Le=None):
    """Paired loci at the ends of the grid intervals the loci rules need: ``(a, b, keep)``,
    ``a``/``b`` ``(N − 1, n)``, ``keep (N − 1,)`` the intervals :func:`_loci_screen` keeps
    (elsewhere ``a``, ``b`` are placeholders the rules must not read).

    Eigenvalues of ``L`` by the XLA QR kernel (:func:`._kernels.eigvals`): when at most half
    the frequencies end a kept interval, at those only, gathered in one block of ``N/2``
    (:func:`._kernels.compacted`; a kernel launch costs per block), and the kept intervals
    paired likewise; else (and under ``vmap``, where a ``cond`` runs both branches) at every
    frequency (the compaction pays when few intervals are kept: benchmarks/README.md). With
    ``kernels="lapack"`` (the reference) or ``arrays`` at every frequency. Paired between
    neighbours as the reference tracker does (optimal permutation for ``n ≤ 6`` by
    :func:`._kernels.pair_optimal`, greedy above)."""
    N, n = L.shape[0], L.shape[-1]

    def paired(e):  # eigenvalues (n, N) at every frequency → both ends of every interval
        return e[:, :-1].T, _pair(e[:, :-1], e[:, 1:]).T

    every = jnp.ones(N - 1, dtype=bool)
    if spec.kernels == "lapack":
        return *paired(jnp.linalg.eigvals(L).T), every  # the reference

    def many(_):
        return paired(K.eigvals(K.to_entries(L)))

    if spec.arrays or not SCREEN_LOCI:
        return *many(None), every
    keep = _loci_screen(K.to_entries(L) if Le is None else Le, spec)
    node = jnp.concatenate([keep, jnp.zeros(1, bool)]) | jnp.concatenate([jnp.zeros(1, bool), keep])
    blk = -(-N // 2)

    def few(_):  # at most half the nodes: one block of N/2 (a kernel launch costs per block)
        def eig(idx, sub):
            return (K.eigvals(K.to_entries(L[idx])).T,)

        (e,) = K.compacted(node, eig, (jnp.zeros((N, n), dtype=L.dtype),), blk)

        def pair(idx, sub):
            return (_pair(e[idx].T, e[idx + 1].T).T,)

        (bp,) = K.compacted(keep, pair, (jnp.zeros((N - 1, n), dtype=L.dtype),), blk)
        return e[:-1], bp

    if isinstance(node, _BATCHED):
        # under vmap a cond runs both branches: the whole grid, as without the screen (a vmap
        # of a jit is batched after tracing: there the cond runs both — correct, slower)
        return *many(None), keep
    return *jax.lax.cond(jnp.sum(node) <= blk, few, many, None), keep


def _pair(a, b):
    """``b (n, M)`` ordered to continue ``a (n, M)``: optimal permutation for ``n ≤ 6``
    (:func:`._kernels.pair_optimal`), greedy above (as the reference tracker)."""
    if a.shape[0] <= _MAX_PERMUTATION_N:
        return K.pair_optimal(a, b)
    return jax.vmap(_match_greedy)(a.T, b.T).T


def _smallest(score, k):
    """Indices of the ``k`` smallest of ``score (M,)`` in increasing order, the lowest index
    first on ties (as ``lax.top_k`` of ``−score``), and whether each is finite: ``k`` argmin
    passes (``top_k`` sorts the whole array; ``k`` is 4)."""
    score = jnp.where(jnp.isnan(score), jnp.inf, score)
    sel, fin = [], []
    for _ in range(k):
        j = jnp.argmin(score)
        sel.append(j)
        fin.append(jnp.isfinite(score[j]))
        score = score.at[j].set(jnp.inf)
    return jnp.stack(sel), jnp.stack(fin)


def _loci_candidates(a, b, keep):
    """The ``_N_REFINE`` best grid candidates of each kind (gain margin: negative-real-axis
    crossings; phase margin: unit-circle crossings) of the paired loci ``a``/``b`` on the
    intervals ``keep``: grid interval ``k``, the locus' ends ``la``/``lb`` and whether the
    candidate exists (``ok``), gain-margin candidates first."""
    C, n = a.shape
    okg, _, gval = phase_crossing(a, b)
    okp, _, pval = gain_crossing(a, b)
    okg, okp = okg & keep[:, None], okp & keep[:, None]
    nr = min(_N_REFINE, C * n)
    sels, oks = [], []
    for ok, grid_val in ((okg, gval), (okp, pval)):
        score = jnp.where(ok, jnp.abs(grid_val), jnp.inf).ravel()
        sel, fin = _smallest(score, nr)
        sels.append(sel)
        oks.append(fin)
    sel = jnp.concatenate(sels)
    k, li = sel // n, sel % n  # grid interval k = [ω_k, ω_{k+1}], locus li
    gm = jnp.arange(2 * nr) < nr
    return dict(k=k, la=a[k, li], lb=b[k, li], ok=jnp.concatenate(oks), gm=gm)


def _loci_problem(task, L_fn):
    """``(f_of, lam_at)`` of the loci candidates ``task`` (flat, any number): the function
    Illinois zeroes (``Im λ`` for a gain margin, ``log|λ|`` for a phase margin) and the
    locus at ``t`` in its grid interval (Newton from the interpolated grid ends). There is
    no early stop on ``|f|``: a crossing whose locus meets the axis at a shallow angle has
    ``f`` at rounding level over a stretch of ``t``, and stopping anywhere in it moved the
    crossing frequency by ~1e-8 between the XLA and LAPACK paths (1 of 1000 cu5 draws)."""
    sel_ok, k, la, lb, is_gm = task["ok"], task["k"], task["la"], task["lb"], task["gm"]
    interp = _Local(task["L"], task["lw"], L_fn)
    c = jnp.arange(k.shape[0])
    x0, x1 = interp.lww[c, k], interp.lww[c, k + 1]

    def f_of(lam):
        return jnp.where(is_gm, jnp.imag(lam), jnp.log(jnp.abs(lam)))

    def lam_at(t):
        x = x0 + t * (x1 - x0)
        return K.eig_newton(K.to_entries(interp(c, k, x)), la + t * (lb - la), active=sel_ok)

    return f_of, lam_at


def _loci_refined(task, L_fn):
    """The loci candidates ``task`` (flat: every candidate of one loop, or of many) refined:
    ``(t, λ)`` each (Illinois on ``Im λ`` resp. ``log|λ|`` of the locus followed by Newton,
    :func:`._kernels.eig_newton`). Every candidate gets ``_STAGE1`` steps together; the
    few that need more (a locus that moves far within its grid interval) continue in blocks
    of ``_BLOCK``, so they do not make every candidate pay their step count."""
    f_of, lam_at = _loci_problem(task, L_fn)
    la, lb, sel_ok = task["la"], task["lb"], task["ok"]
    # candidates that do not exist (fewer crossings than slots): no bracket, so they
    # neither keep Illinois nor Newton running
    fa = jnp.where(sel_ok, f_of(la), 1.0)
    fb = jnp.where(sel_ok, f_of(lb), 1.0)
    c1 = _illinois_state(_illinois_init(la, lb, fa, fb), lam_at, f_of, _STAGE1)
    state = {k: v for k, v in c1.items() if k != "it"}

    def more(idx, sub_state):
        sub = {k: v[idx] for k, v in task.items()}
        f2, lam2 = _loci_problem(sub, L_fn)
        c2 = dict(zip(state, sub_state, strict=True))
        c2 = _illinois_state(c2, lam2, f2, _ROOT_ITERS - _STAGE1)
        return tuple(c2[k] for k in state)

    out = K.compacted(~_illinois_done(c1), more, tuple(state.values()), _BLOCK)
    out = dict(zip(state, out, strict=True))
    return out["best_t"], out["best_lam"]


def _loci_select(task, ts, lam):
    """Worst refined gain and phase margins of one loop's candidates:
    ``((gm_db, omega), (pm_deg, omega))``."""
    sel_ok = task["ok"]
    nr = sel_ok.shape[0] // 2
    c = jnp.arange(2 * nr)
    x0, x1 = task["lw"][c, task["k"]], task["lw"][c, task["k"] + 1]
    w = jnp.exp(x0 + ts * (x1 - x0))
    gm = jnp.where(sel_ok & (jnp.real(lam) < 0), -_DB * jnp.log(jnp.abs(lam)), jnp.inf)[:nr]
    pm = jnp.where(sel_ok, _pm_deg(lam), jnp.inf)[nr:]
    out = []
    for val, ww, okk in ((gm, w[:nr], jnp.isfinite(gm)), (pm, w[nr:], sel_ok[nr:])):
        j = jnp.argmin(jnp.abs(val))
        out.append((val[j], jnp.where(okk[j], ww[j], jnp.nan)))
    return out
