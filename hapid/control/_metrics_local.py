"""The loop near one grid interval, for the refinement pass of
:func:`~hapid.control.loop_metrics`: the vectorized Illinois false-position root finder
(:func:`_illinois_state`, shared by the σ̄ crossings and the loci), the window of grid nodes
around an interval (:func:`_windows`) and ``L(jω)`` on it (:class:`_Local`: exact through
``L_fn``, else a 4-point Lagrange interpolant in log ω)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .. import _config  # noqa: F401  (float64)

_ROOT_ITERS = 30
_T_TOL = 1e-14  # Illinois: bracket width in t ∈ [0, 1] that counts as converged


def _illinois(f, fa, fb, iters=_ROOT_ITERS):
    """Root of ``f(t)`` on ``t ∈ [0, 1]`` given ``fa = f(0)``, ``fb = f(1)`` of opposite
    signs (vectorized over the candidates), by Illinois false position
    (:func:`_illinois_state` with ``f`` itself as the value carried). Returns the evaluated
    point of smallest ``|f|`` (the bracket ends included): false position converges from
    one side, so the bracket's midpoint can stay far from the root while one end sits on
    it."""
    c = _illinois_state(_illinois_init(fa, fb, fa, fb), f, lambda v: v, iters)
    return c["best_t"]


def _illinois_init(la, lb, fa, fb):
    """Start of :func:`_illinois_state`: the bracket ``t ∈ [0, 1]`` with the values ``la``,
    ``lb`` (e.g. the locus) and ``f`` = ``fa``, ``fb`` at its ends."""
    a_best = jnp.abs(fa) <= jnp.abs(fb)
    return dict(
        it=jnp.asarray(0), ta=jnp.zeros_like(fa), tb=jnp.ones_like(fb), fa=fa, fb=fb,
        side=jnp.zeros(fa.shape, dtype=jnp.int32),
        best_t=jnp.where(a_best, 0.0, 1.0), best_f=jnp.where(a_best, jnp.abs(fa), jnp.abs(fb)),
        best_lam=jnp.where(a_best, la, lb),
    )  # fmt: skip


def _illinois_done(c):
    fa, fb = c["fa"], c["fb"]
    bracket = ((fa >= 0) != (fb >= 0)) & jnp.isfinite(fa) & jnp.isfinite(fb)
    return ~bracket | (c["best_f"] == 0) | (jnp.abs(c["tb"] - c["ta"]) <= _T_TOL)


def _illinois_state(c, lam_at, f_of, iters):
    """Illinois false position on ``f_of(lam_at(t))``, ``t ∈ [0, 1]`` (vectorized over the
    candidates; ``lam_at(t)`` e.g. the eigenvalue of ``L`` at ``t`` nearest the locus'
    interpolated grid ends), from the state ``c`` (:func:`_illinois_init`), at most
    ``iters`` more steps. Stops when every candidate has converged (``f = 0`` hit or the
    bracket below ``_T_TOL``; a candidate without a sign change counts as converged); a
    converged candidate keeps its state, so its result does not depend on the
    other candidates of the batch. Returns the state; ``best_t``/``best_lam``: the evaluated
    point of smallest ``|f|`` and its value."""

    def body(c):
        busy = ~_illinois_done(c)
        ta, tb, fa, fb, side = c["ta"], c["tb"], c["fa"], c["fb"], c["side"]
        den = fb - fa
        t = jnp.where(
            den != 0, (ta * fb - tb * fa) / jnp.where(den != 0, den, 1.0), 0.5 * (ta + tb)
        )
        t = jnp.clip(t, jnp.minimum(ta, tb), jnp.maximum(ta, tb))
        lam = lam_at(t)
        ft = f_of(lam)
        better = jnp.abs(ft) < c["best_f"]
        same_a = (ft >= 0) == (fa >= 0)
        # Illinois: halve the stale end's value when the same end is kept twice
        new = dict(
            it=c["it"] + 1,
            ta=jnp.where(same_a, t, ta), tb=jnp.where(same_a, tb, t),
            fa=jnp.where(same_a, ft, jnp.where(side == -1, 0.5 * fa, fa)),
            fb=jnp.where(same_a, jnp.where(side == 1, 0.5 * fb, fb), ft),
            side=jnp.where(same_a, 1, -1).astype(jnp.int32),
            best_t=jnp.where(better, t, c["best_t"]),
            best_f=jnp.where(better, jnp.abs(ft), c["best_f"]),
            best_lam=jnp.where(better, lam, c["best_lam"]),
        )  # fmt: skip
        # a candidate that is done keeps its state: its result does not depend on the batch
        return {k: v if k == "it" else jnp.where(busy, v, c[k]) for k, v in new.items()}

    def cond(c):
        return (c["it"] < iters) & ~jnp.all(_illinois_done(c))

    return jax.lax.while_loop(cond, body, dict(c, it=jnp.asarray(0)))


def _lagrange_weights(x, nodes):
    """4-point Lagrange weights at ``x (C,)`` for nodes ``(C, 4)``."""
    w = []
    for j in range(4):
        num = jnp.ones_like(x)
        for m in range(4):
            if m != j:
                num = num * (x - nodes[:, m]) / (nodes[:, j] - nodes[:, m])
        w.append(num)
    return jnp.stack(w, axis=1)


_W = (
    8  # grid nodes carried per refinement task (covers the cubic's nodes of intervals k − 1..k + 1)
)


def _windows(L, lw, k):
    """Grid nodes around each task's grid interval ``k (C,)``: ``(L_win (C, W, n, n),
    lw_win (C, W), k_local (C,))`` with ``W = min(8, N)`` starting at ``clip(k − 3, 0, N − W)``,
    so the local interpolant picks the same nodes as one on the whole grid would."""
    N = L.shape[0]
    W = min(_W, N)
    s = jnp.clip(k - 3, 0, N - W)
    idx = s[:, None] + jnp.arange(W)[None]
    return L[idx], lw[idx], k - s


class _Local:
    """``L`` at log-frequencies ``x`` near each refinement task's grid interval: ``L_fn`` if
    given, else a 4-point Lagrange interpolant of the task's window of grid values (linear
    when the grid has fewer than 4 points). Task ``c``, local interval ``k``: the same nodes
    as the whole grid's interpolant (:func:`_windows`)."""

    def __init__(self, Lw, lww, L_fn):
        self.Lw, self.lww, self.L_fn = Lw, lww, L_fn
        self.W = lww.shape[-1]

    def __call__(self, c, k, x):
        if self.L_fn is not None:
            return jnp.asarray(self.L_fn(jnp.exp(x)), dtype=jnp.complex128)
        W, lww, Lw = self.W, self.lww, self.Lw
        if W < 4:
            k = jnp.clip(k, 0, W - 2)
            x0, x1 = lww[c, k], lww[c, k + 1]
            t = (x - x0) / (x1 - x0)
            return Lw[c, k] + t[:, None, None] * (Lw[c, k + 1] - Lw[c, k])
        j0 = jnp.clip(k - 1, 0, W - 4)
        idx = j0[:, None] + jnp.arange(4)[None]
        w = _lagrange_weights(x, lww[c[:, None], idx])
        return jnp.einsum("cj,cjab->cab", w.astype(Lw.dtype), Lw[c[:, None], idx])

    def interval(self, c, x):
        """Local grid interval of ``x`` in task ``c``'s window (the node ≤ x, clipped)."""
        k = jnp.sum(self.lww[c] <= x[:, None], axis=1) - 1
        return jnp.clip(k, 0, self.W - 2)
