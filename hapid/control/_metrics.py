# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Loop metrics that compute only what is asked, with crossings refined off the grid.

:func:`loop_metrics` decides stability by the same rules as :func:`~hapid.control.analyze_loop`
(the LAPACK reference, which stays): generalized Nyquist on ``det(I + L)`` with
``P_ol`` = open-loop RHP poles of plant *and* controller, the grid resolution check of
``det(I + L)`` and of every characteristic locus ``1 + λ_i``, and the singularity check
``σ̲(I + L) ≤ rtol · max(1, σ̄(I + L))``. It differs in how much it computes:

* ``det(I + L)`` and ``S = (I + L)⁻¹`` by the XLA kernels of :mod:`._kernels` (no LAPACK);
* σ̄ of ``S``, ``T`` (and ``S − T``) is *bounded* cheaply at every frequency and computed
  exactly (Jacobi on ``AᴴA``) only where the bounds do not decide — around the first
  crossing of ``1 − 1/√2`` and around the peaks;
* eigenvalues of ``L`` (the loci) by the XLA QR kernel (:func:`._kernels.eigvals`:
  Hessenberg + Wilkinson-shifted QR, no LAPACK), paired between neighbouring frequencies by
  the reference tracker's rule (optimal permutation, by dynamic programming over subsets:
  :func:`._kernels.pair_optimal`) — only on the grid intervals where a disc that provably
  holds every eigenvalue (centre ``tr L/n``, radius ``‖L − tr L/n·I‖_F``) leaves the loci
  rules anything to decide (:func:`_loci_screen`; where the model is right the loci cluster
  about ``g`` and most intervals are left out);
* one path, no whole-grid fallback: where the cheap bounds do not decide (singularity,
  bandwidth, peaks), exact values are computed for the undecided points ``n_candidates`` at
  a time in a ``while_loop`` — the work follows the count of undecided points, and under
  ``vmap`` nothing is computed twice (``exact_fallback`` is always false; kept for callers).

Two passes, each pure and jit/vmap-able: :func:`grid_pass` does the work at every grid
frequency (the verdict; for each asked metric the grid interval to refine and a window of
grid nodes around it) and :func:`refine_pass` the few small sequential steps (Illinois,
Newton, multisection). :func:`metrics_screened` runs both in one program; a caller with
many loops (``robust_check``) runs the grid pass per loop and the refinement pass once,
vmapped, for all of them, so the refinement's step count is paid once.

Crossings are **refined**, not read on the grid: the iso-bandwidth (σ̄(T − I) = σ̄(S)
reaching ``1 − 1/√2``), gain/phase crossovers of the loci and the peak of σ̄(T) are solved
for on ``L(jω)`` itself — given ``L_fn`` (``omega (M,) → L(jω) (M, n, n)``) exactly, else on
a local cubic (4-point Lagrange in log ω) interpolant of the grid's ``L`` — so the same loop
on different reasonable grids gives the same numbers (to ~0.01 dB / 0.01° / 0.001 Hz on the
paper's loops).
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Complex, Float

from .. import _config  # noqa: F401  (float64)
from .._aot import cached_jit
from . import _kernels as K
from ._lapack import after, lu_det_solve
from ._loop import loop_arrays, scalar_fields
from ._margins import _DB, _pm_deg, disk_margin_from_peak, gain_crossing, phase_crossing
from ._nyquist import (
    _MAX_PERMUTATION_N,
    _match_greedy,
    nyquist_encirclements,
    nyquist_verdict,
)

TWO_PI = 2.0 * np.pi
ISO_THRESHOLD = 1.0 - 1.0 / np.sqrt(2.0)
_ROOT_ITERS = 30
_T_TOL = 1e-14  # Illinois: bracket width in t ∈ [0, 1] that counts as converged
_SECTIONS = 16  # points per multisection step (peaks)
_SECTION_STEPS = 4  # bracket × (2/17)^4 ≈ 2e-4, then
_PARABOLA_STEPS = 2  # parabolic steps on the best point
_N_REFINE = 4
_STAGE1 = 8  # Illinois steps every loci candidate gets; the rest continue in blocks
_BLOCK = 64
# a value being batched by vmap (private to JAX; if it moves, the cond runs under vmap too)
_BATCHED = getattr(importlib.import_module("jax._src.interpreters.batching"), "BatchTracer", ())
SCREEN_LOCI = True  # False: eigenvalues at every frequency (for benchmarks: read at trace time)


@dataclasses.dataclass(frozen=True)
class MetricsSpec:
    """What :func:`loop_metrics` computes (static, hashable). The verdict is always computed.

    - ``bandwidth``: iso-bandwidth (first ω where σ̄(T − I) reaches 1 − 1/√2), refined.
    - ``margins``: worst gain/phase margins over the characteristic loci, refined.
    - ``t_peak``: peak of σ̄(T) and its frequency, refined.
    - ``disk``: balanced disk margin ``2/max σ̄(S − T)`` (peak refined).
    - ``arrays``: also the per-frequency ``freq_hz``, ``sv_T_minus_I`` (σ̄ only, ``(N,)``)
      and tracked ``loci`` ``(N, n)`` (costs the full eigenvalue stack).
    - ``singular_rtol``, ``max_phase_step``: as :func:`~hapid.control.analyze_loop`.
    - ``n_candidates``: how many undecided grid points get exact values per step of the
      refinement loops (a work-size knob; results do not depend on it).
    - ``kernels``: ``"xla"`` (default) or ``"lapack"`` (LU/SVD custom calls; the reference
      the kernels are tested against).
    """

    bandwidth: bool = True
    margins: bool = True
    t_peak: bool = True
    disk: bool = False
    arrays: bool = False
    singular_rtol: float = 1e-9
    max_phase_step: float = float(np.pi / 2)
    n_candidates: int = 128
    kernels: str = "xla"
    # additions for the one-answer callers (analyze, paper, tune):
    # ``literal``: also the paper-literal iso-bandwidth (last upward crossing of σ̄(T − I)
    # over 1 − 1/√2, refined; exact σ̄ on the whole grid); ``full_sv``: ``sv_T_minus_I``
    # (with ``arrays``) holds every singular value ``(N, n)``, largest first (figures 5, 10).
    # ``disk`` also fills ``disk_gm_db``/``disk_pm_deg`` (from α, as ``disk_margin_from_peak``).
    literal: bool = False
    full_sv: bool = False


_SCALARS = (
    "stable",
    "n_encirclements",
    "n_closed_loop_rhp",
    "singular",
    "nyquist_resolved",
    "iso_bandwidth_hz",
    "gm_db",
    "gm_freq_hz",
    "pm_deg",
    "pm_freq_hz",
    "t_peak_db",
    "t_peak_hz",
    "disk_margin",
    "iso_bandwidth_literal_hz",
    "disk_gm_db",
    "disk_pm_deg",
)


class LoopMetrics(eqx.Module):
    """Result of :func:`loop_metrics` (0-d arrays, or ``(B,)`` when vmapped; Hz, dB, deg).

    Verdict: ``stable``, ``n_encirclements``, ``n_closed_loop_rhp``, ``singular``,
    ``nyquist_resolved`` (as :class:`~hapid.control.LoopReport`). Performance (NaN when not
    stable or not asked): ``iso_bandwidth_hz`` (0: above the threshold at the first grid
    point, inf: never reached), ``t_peak_db``/``t_peak_hz``. Margins (any loop, NaN when not
    asked; inf/NaN-frequency when no crossing): ``gm_db``/``gm_freq_hz``, ``pm_deg``/
    ``pm_freq_hz``. ``disk_margin`` (0 when not stable, NaN when not asked).
    ``exact_fallback``: always false (there is no whole-grid fallback any more; kept for callers).
    Arrays (``spec.arrays``, else ``None``): ``freq_hz (N,)``, ``sv_T_minus_I (N,)`` (σ̄),
    ``loci (N, n)``.
    """

    stable: Bool[Array, ...]
    n_encirclements: Float[Array, ...]
    n_closed_loop_rhp: Float[Array, ...]
    singular: Bool[Array, ...]
    nyquist_resolved: Bool[Array, ...]
    iso_bandwidth_hz: Float[Array, ...]
    gm_db: Float[Array, ...]
    gm_freq_hz: Float[Array, ...]
    pm_deg: Float[Array, ...]
    pm_freq_hz: Float[Array, ...]
    t_peak_db: Float[Array, ...]
    t_peak_hz: Float[Array, ...]
    disk_margin: Float[Array, ...]
    iso_bandwidth_literal_hz: Float[Array, ...]
    disk_gm_db: Float[Array, ...]
    disk_pm_deg: Float[Array, ...]
    exact_fallback: Bool[Array, ...]
    freq_hz: Float[Array, "... N"] | None = None
    sv_T_minus_I: Float[Array, "... N"] | None = None
    loci: Complex[Array, "... N n"] | None = None

    @property
    def ok(self):
        """True when the loop is stable with a resolved Nyquist count (bool array if batched)."""
        return self.stable & self.nyquist_resolved & ~self.singular

    @property
    def status(self):
        """``"stable"``, ``"unstable"``, ``"singular"`` (closed-loop pole on the axis) or
        ``"unresolved"`` (grid too coarse / not reaching the ends); numpy array if batched."""
        st = np.asarray(self.stable)
        sg = np.asarray(self.singular)
        rs = np.asarray(self.nyquist_resolved)
        out = np.where(
            sg, "singular", np.where(~rs, "unresolved", np.where(st, "stable", "unstable"))
        )
        return str(out) if out.ndim == 0 else out

    def summary(self) -> dict:
        """Scalar fields as python ``bool``/``int``/``float`` (lists when batched), plus
        ``status``. Non-finite values stay ``nan``/``inf``."""
        out = scalar_fields(self, _SCALARS)
        s = self.status
        out["status"] = s if isinstance(s, str) else s.tolist()
        return out


# --------------------------------------------------------------------------------------
# helpers


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


# --------------------------------------------------------------------------------------
# the analysis: a grid pass (every frequency) and a refinement pass (a few small tasks)
#
# The grid pass decides the verdict and finds, for each asked metric, the grid interval to
# refine; it hands the refinement pass a window of grid nodes around each (``_windows``).
# The refinement pass is sequential (Illinois, Newton, multisection) on a handful of
# small matrices: on its own its cost is the per-step overhead, which a caller with many
# loops (``robust_check``) shares by running it once, vmapped, over all of them.


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
    frequency. Measured at N = 1000 (grid pass, one process): default loop draws of cu5
    (a third of the intervals kept) 1.3× faster, parameter draws (93 % kept) 0.9×. With
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


def _interval_task(L, lw, i, j):
    """A refinement task on grid interval ``[i, j]`` (``j`` = ``i`` or ``i + 1``): its
    window of nodes and the local indices."""
    Lw, lww, il = _windows(L, lw, jnp.reshape(i, (1,)))
    return dict(L=Lw, lw=lww, i=il[0], j=il[0] + (j - i))


def grid_pass(P, G, omega, p_ol, spec: MetricsSpec):
    """Everything :func:`loop_metrics` does at every grid frequency: the verdict, and for
    each asked metric the grid interval and window of nodes to refine (``tasks``). Pure,
    jit/vmap-able. Returns ``(out, tasks)``: ``out`` the verdict fields (and the arrays),
    ``tasks`` what :func:`refine_pass` needs."""
    kern = spec.kernels
    N, n, _ = P.shape
    size = spec.n_candidates
    Le = None
    if kern == "xla":  # the product entry by entry, batch last, as the kernels read it
        Le = K.matmul(K.to_entries(P), K.to_entries(G))
        L = K.from_entries(Le)
    else:
        L = jnp.einsum("wij,wjk->wik", P, G)
    eye = jnp.eye(n, dtype=L.dtype)
    IL = L + eye
    if kern == "xla":  # the whole grid: elimination without row exchanges where it is safe
        det, S = K.det_inv_screened(K.to_entries(IL))
        S = K.from_entries(S)
    else:
        det, S = _det_inv(IL, kern, unroll=True)
    lw = jnp.log(omega)

    # --- singular I + L: σ̲(I+L) = 1/σ̄(S) ≤ rtol·max(1, σ̄(I+L)) ---------------------------
    rtol = spec.singular_rtol
    fS = jnp.sqrt(K.fro2(K.to_entries(S)))
    fIL = jnp.sqrt(K.fro2(K.to_entries(IL)))
    finite_IL = jnp.isfinite(fIL)
    finS = jnp.isfinite(fS)
    # the bounds decide almost everywhere; exact σ̄ at the ambiguous frequencies (at most 4
    # in the screened path, 256 in the exact one: a factor-n band around rtol is rare)
    rn = np.sqrt(n)
    sure_not = finS & (1.0 / fS > rtol * jnp.maximum(1.0, fIL))
    sure = ~finS | (rn / fS <= rtol * jnp.maximum(1.0, fIL / rn))
    amb = finite_IL & ~sure_not & ~sure

    def amb_test(i):
        s2 = _sigma_exact(jnp.concatenate([S[i], IL[i]]), kern)
        sS, sIL = s2[: i.shape[0]], s2[i.shape[0] :]
        return jnp.isfinite(sS) & (1.0 / sS <= rtol * jnp.maximum(1.0, sIL))

    sing_k = _fill_where(amb, amb_test, finite_IL & sure, 4)
    singular = jnp.any(sing_k)

    n_enc, _, resolved = nyquist_encirclements(det, spec.max_phase_step)
    p_ol = jnp.asarray(p_ol, dtype=jnp.float64)

    # --- loci where needed: resolution of every 1 + λ_i, margin candidates --------------------
    la, lb, keep = _loci_pairs(after(L, det), spec, Le)
    dphi = jnp.where(keep[:, None], jnp.abs(jnp.angle((1.0 + lb) / (1.0 + la))), 0.0)
    loci_ok = ~jnp.any(~(dphi < spec.max_phase_step))
    resolved = resolved & loci_ok
    stable = nyquist_verdict(n_enc, p_ol, resolved, singular)

    out = dict(
        stable=stable,
        n_encirclements=n_enc,
        n_closed_loop_rhp=n_enc + p_ol,
        singular=singular,
        nyquist_resolved=resolved,
    )
    tasks = {}
    if spec.margins:
        t = _loci_candidates(la, lb, keep)
        t["L"], t["lw"], t["k"] = _windows(L, lw, t["k"])
        tasks["margins"] = t
    if spec.bandwidth:
        lo, hi = K.sigma_bounds(K.to_entries(S))
        k, any_above = _first_above(lambda i: _sigma_exact(S[i], kern), lo, hi, ISO_THRESHOLD, size)
        t = _interval_task(L, lw, jnp.maximum(k - 1, 0), k)
        tasks["bandwidth"] = t | dict(first=k == 0, none=~any_above)
    kinds, grid = [], []
    if spec.t_peak:
        kinds.append("T")
        grid.append(_peak_grid(eye - S, size, kern))
    if spec.disk:
        kinds.append("SmT")
        grid.append(_peak_grid(2.0 * S - eye, size, kern))
    if kinds:
        kpk = jnp.stack([k for k, _ in grid])
        Lw, lww, _ = _windows(L, lw, jnp.minimum(kpk, N - 2))
        tasks["peaks"] = dict(
            L=Lw, lw=lww, v=jnp.stack([v for _, v in grid]), x0=lw[kpk],
            a=lw[jnp.maximum(kpk - 1, 0)], b=lw[jnp.minimum(kpk + 1, N - 1)],
        )  # fmt: skip
    # σ̄(S) on the whole grid only for what needs it (the literal bandwidth, the arrays)
    sig_S_all = None
    if spec.literal or (spec.arrays and not spec.full_sv):
        sig_S_all = _sigma_exact(S, kern)
    if spec.literal:
        # the end of the last sub-threshold stretch: inf if below at the last point, 0 if
        # never below
        below = sig_S_all < ISO_THRESHOLD
        j = N - 1 - jnp.argmax(below[::-1])
        t = _interval_task(L, lw, j, jnp.minimum(j + 1, N - 1))
        tasks["literal"] = t | dict(last=j == N - 1, none=~jnp.any(below))
    if spec.arrays:
        from ._nyquist import characteristic_loci

        if spec.full_sv:
            sv = jnp.linalg.svd(after(S, stable), compute_uv=False)
        else:
            sv = sig_S_all
        out.update(freq_hz=omega / TWO_PI, sv_T_minus_I=sv, loci=characteristic_loci(after(L, sv)))
    return out, tasks


def refine_pass(out, tasks, L_fn, spec: MetricsSpec):
    """The refined metrics from :func:`grid_pass`'s ``(out, tasks)``: a dict of every
    :class:`LoopMetrics` field. Pure, jit/vmap-able; ``L_fn`` as :func:`loop_metrics`."""
    kern = spec.kernels
    stable = out["stable"]
    nan = jnp.full(jnp.shape(stable), jnp.nan)
    res = dict(out)
    for name in _SCALARS[5:]:
        res[name] = nan
    if spec.margins:
        t = tasks["margins"]
        loci = tasks.get("loci")  # (t, λ) refined by the caller (many loops at once), or here
        (g, gw), (p, pw) = _loci_select(t, *(loci or _loci_refined(t, L_fn)))
        res.update(gm_db=g, gm_freq_hz=gw / TWO_PI, pm_deg=p, pm_freq_hz=pw / TWO_PI)
    if spec.bandwidth:
        t = tasks["bandwidth"]
        w = _threshold_crossing(
            0, t["i"], t["j"], ISO_THRESHOLD, _Local(t["L"], t["lw"], L_fn), kern
        )
        bw = jnp.where(t["none"], jnp.inf, jnp.where(t["first"], 0.0, w))
        res["iso_bandwidth_hz"] = jnp.where(stable, bw / TWO_PI, nan)
    kinds = tuple(k for k, on in (("T", spec.t_peak), ("SmT", spec.disk)) if on)
    if kinds:
        t = tasks["peaks"]
        pk = dict(zip(kinds, _peaks(t, kinds, _Local(t["L"], t["lw"], L_fn), kern), strict=True))
    if spec.t_peak:
        v, w = pk["T"]
        res["t_peak_db"] = jnp.where(stable, _DB * jnp.log(v), nan)
        res["t_peak_hz"] = jnp.where(stable, w / TWO_PI, nan)
    if spec.disk:
        v, _ = pk["SmT"]
        res["disk_margin"] = jnp.where(stable, 2.0 / v, 0.0)
        dm = disk_margin_from_peak(v)
        res["disk_gm_db"] = jnp.where(stable, dm["disk_gm_db"], 0.0)
        res["disk_pm_deg"] = jnp.where(stable, dm["disk_pm_deg"], 0.0)
    if spec.literal:
        t = tasks["literal"]
        w = _threshold_crossing(
            0, t["i"], t["j"], ISO_THRESHOLD, _Local(t["L"], t["lw"], L_fn), kern
        )
        lit = jnp.where(t["none"], 0.0, jnp.where(t["last"], jnp.inf, w))
        res["iso_bandwidth_literal_hz"] = jnp.where(stable, lit / TWO_PI, nan)
    return res


def refine_many(out, tasks, L_fn, spec: MetricsSpec):
    """:func:`refine_pass` of many loops at once: ``out``/``tasks`` are :func:`grid_pass`'s
    results stacked on a leading axis ``(D, ...)``. Every loop's loci candidates are refined
    as one flat batch (its few slow candidates in compacted blocks), the rest vmapped; the
    sequential steps are paid once for the ``D`` loops. Returns the fields ``(D,)``."""
    if "margins" in tasks:
        m = tasks["margins"]
        D, C = m["k"].shape
        ts, lam = _loci_refined(jax.tree.map(lambda a: a.reshape((D * C,) + a.shape[2:]), m), L_fn)
        tasks = dict(tasks, loci=(ts.reshape(D, C), lam.reshape(D, C)))
    return jax.vmap(lambda o, t: refine_pass(o, t, L_fn, spec))(out, tasks)


def _check(P, G, omega):
    P, G, omega = loop_arrays(P, G, omega, "loop_metrics")
    if P.shape[0] < 2:
        raise ValueError("loop_metrics: at least 2 frequencies are needed")
    return P, G, omega


def metrics_screened(P, G, omega, p_ol, L_fn, spec):
    """The analysis as a dict of :class:`LoopMetrics` fields; pure, jit/vmap-able
    (:func:`grid_pass` then :func:`refine_pass`)."""
    out, tasks = grid_pass(P, G, omega, p_ol, spec)
    return refine_pass(out, tasks, L_fn, spec)


_metrics_jit = cached_jit(metrics_screened)


def _loop_metrics(P, G, omega, p_ol, L_fn, spec):
    if isinstance(P, jax.core.Tracer) or isinstance(p_ol, jax.core.Tracer):
        out = metrics_screened(P, G, omega, p_ol, L_fn, spec)
    else:
        out = _metrics_jit(P, G, omega, p_ol, L_fn, spec)
    return LoopMetrics(**out, exact_fallback=jnp.asarray(False))


def loop_metrics(
    P: Complex[Array, "N n n"],
    G: Complex[Array, "N n n"],
    omega: Float[Array, " N"],
    *,
    p_ol=0,
    spec: MetricsSpec = MetricsSpec(),
    L_fn: Callable | None = None,
) -> LoopMetrics:
    """Verdict and the metrics ``spec`` asks for of the loop ``L = P G`` (negative feedback).

    Args:
        P, G: plant and controller responses ``(N, n, n)`` complex on ``omega``.
        omega: increasing positive frequencies (rad/s), ``(N,)``; as for
            :func:`~hapid.control.analyze_loop` it must reach the loop's real end values
            and resolve the phase of ``det(I + L)``.
        p_ol: open-loop RHP poles of the plant **and** the controller (int or 0-d array;
            traced, so changing it does not recompile).
        spec: :class:`MetricsSpec` (static).
        L_fn: optional ``omega (M,) → L(jω) (M, n, n)`` for exact refinement of crossings
            (static; otherwise a local cubic interpolant of the grid).

    Returns :class:`LoopMetrics`. Called on arrays it runs one jit-compiled program per
    (shapes, spec, L_fn); under ``jit``/``vmap`` it is traced inline (one path).
    """
    P, G, omega = _check(P, G, omega)
    if spec.kernels not in ("xla", "lapack"):
        raise ValueError(f"MetricsSpec.kernels must be 'xla' or 'lapack', got {spec.kernels!r}")
    return _loop_metrics(P, G, omega, jnp.asarray(p_ol, dtype=jnp.float64), L_fn, spec)
