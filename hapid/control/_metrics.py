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
* eigenvalues of ``L`` (the loci) only in grid intervals where a disc containing them
  (centre ``tr L/n``, radius ``‖L − cI‖_F``) allows a gain crossover, a phase crossover or a
  phase step of ``1 + λ`` near ``max_phase_step``; elsewhere the disc proves there is none.
  When more intervals (or frequencies) than ``spec.n_candidates`` need the exact values —
  loops far from "scalar", such as random test loops — the whole grid is computed exactly
  instead (same answers, the reference cost).

Crossings are **refined**, not read on the grid: the iso-bandwidth (σ̄(T − I) = σ̄(S)
reaching ``1 − 1/√2``), gain/phase crossovers of the loci and the peak of σ̄(T) are solved
for on ``L(jω)`` itself — given ``L_fn`` (``omega (M,) → L(jω) (M, n, n)``) exactly, else on
a local cubic (4-point Lagrange in log ω) interpolant of the grid's ``L`` — so the same loop
on different reasonable grids gives the same numbers (to ~0.01 dB / 0.01° / 0.001 Hz on the
paper's loops).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Complex, Float

from .. import _config  # noqa: F401  (float64)
from . import _kernels as K
from ._lapack import after, lu_det_solve
from ._loop import loop_arrays, scalar_fields
from ._margins import _DB, _pm_deg, disk_margin_from_peak, gain_crossing, phase_crossing
from ._nyquist import (
    _MAX_PERMUTATION_N,
    _match_greedy,
    _match_permutation,
    nyquist_encirclements,
    nyquist_verdict,
)

TWO_PI = 2.0 * np.pi
ISO_THRESHOLD = 1.0 - 1.0 / np.sqrt(2.0)
_ROOT_ITERS = 30
_GOLDEN_ITERS = 48
_N_REFINE = 4


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
    - ``n_candidates``: how many grid points/intervals may need exact values before the
      whole grid is computed exactly.
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
    # additions for the one-answer callers (analyze/paper/tune; issue 16):
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
    ``exact_fallback``: the screen did not decide and the whole grid was computed exactly.
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
    signs (vectorized over the candidates). Returns ``(t, aux)`` of the last evaluation at
    the bracket end that kept the sign of ``fb`` (Illinois false position)."""
    ta = jnp.zeros_like(fa)
    tb = jnp.ones_like(fb)

    def body(_, c):
        ta, tb, fa, fb, side = c
        den = fb - fa
        t = jnp.where(
            den != 0, (ta * fb - tb * fa) / jnp.where(den != 0, den, 1.0), 0.5 * (ta + tb)
        )
        t = jnp.clip(t, jnp.minimum(ta, tb), jnp.maximum(ta, tb))
        ft = f(t)
        same_a = (ft >= 0) == (fa >= 0)
        # Illinois: halve the stale end's value when the same end is kept twice
        fa_new = jnp.where(same_a, ft, jnp.where(side == -1, 0.5 * fa, fa))
        fb_new = jnp.where(same_a, jnp.where(side == 1, 0.5 * fb, fb), ft)
        ta_new = jnp.where(same_a, t, ta)
        tb_new = jnp.where(same_a, tb, t)
        side = jnp.where(same_a, 1, -1).astype(jnp.int32)
        return ta_new, tb_new, fa_new, fb_new, side

    side = jnp.zeros(fa.shape, dtype=jnp.int32)
    ta, tb, fa, fb, _ = jax.lax.fori_loop(0, iters, body, (ta, tb, fa, fb, side))
    return 0.5 * (ta + tb)


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


class _Interp:
    """``L`` at log-frequencies ``x`` near grid interval ``k``: ``L_fn`` if given, else a local
    4-point Lagrange interpolant of the grid values (linear when N < 4)."""

    def __init__(self, L, lw, L_fn):
        self.L, self.lw, self.L_fn = L, lw, L_fn
        self.N = L.shape[0]

    def __call__(self, k, x):
        if self.L_fn is not None:
            return jnp.asarray(self.L_fn(jnp.exp(x)), dtype=jnp.complex128)
        N, lw, L = self.N, self.lw, self.L
        if N < 4:
            k = jnp.clip(k, 0, N - 2)
            t = (x - lw[k]) / (lw[k + 1] - lw[k])
            return L[k] + t[:, None, None] * (L[k + 1] - L[k])
        j0 = jnp.clip(k - 1, 0, N - 4)
        idx = j0[:, None] + jnp.arange(4)[None]
        w = _lagrange_weights(x, lw[idx])
        return jnp.einsum("cj,cjab->cab", w.astype(L.dtype), L[idx])

    def interval(self, x):
        k = jnp.searchsorted(self.lw, x, side="right") - 1
        return jnp.clip(k, 0, self.N - 2)


def _sigma_exact(A, kernels):
    """σ̄ of ``(..., n, n)`` matrices."""
    if kernels == "lapack":
        return jnp.linalg.svd(A, compute_uv=False)[..., 0]
    return K.sigma_max(K.to_entries(A))


def _det_inv(IL, kernels, unroll=False):
    if kernels == "lapack":
        eye = jnp.eye(IL.shape[-1], dtype=IL.dtype)
        return lu_det_solve(IL, jnp.broadcast_to(eye, IL.shape))
    det, S = K.det_inv(K.to_entries(IL), unroll=unroll)
    return det, K.from_entries(S)


def _gather(flag, size):
    """First ``size`` indices where ``flag`` (padded with the last index), count."""
    idx = jnp.nonzero(flag, size=size, fill_value=flag.shape[0] - 1)[0]
    return idx, jnp.sum(flag)


def _pair(a, b):
    """Order the eigenvalues ``b (C, n)`` to continue ``a (C, n)`` (as the reference tracker)."""
    n = a.shape[-1]
    if n <= _MAX_PERMUTATION_N:
        perms = jnp.asarray(np.array(list(itertools.permutations(range(n)))), dtype=jnp.int32)
        return jax.vmap(lambda p, c: _match_permutation(p, c, perms))(a, b)
    return jax.vmap(_match_greedy)(a, b)


# --------------------------------------------------------------------------------------
# the analysis


def _threshold_crossing(i, j, thr, interp, lw, kernels):
    """ω (rad/s) in grid interval ``[i, j]`` where σ̄(S) = ``thr``: Illinois on the exact (or
    interpolated) S over log ω, bracketed by its values at the interval's grid ends."""

    def f(t):
        x = lw[i] + t * (lw[j] - lw[i])
        return _sigma_of_S(interp(jnp.broadcast_to(i, x.shape), x), kernels) - thr

    fab = f(jnp.array([0.0, 1.0]))
    t = _illinois(f, fab[:1], fab[1:])[0]
    return jnp.exp(lw[i] + t * (lw[j] - lw[i]))


def _first_crossing(sig_fn, lo, hi, thr, interp, lw, size, exact_all, kernels):
    """Refined lowest ω where σ̄(S) reaches ``thr``: (omega, overflow)."""
    N = lo.shape[0]
    if exact_all:
        sig = sig_fn(jnp.arange(N))
        above = sig >= thr
        overflow = jnp.asarray(False)
    else:
        maybe = hi >= thr
        sure = lo >= thr
        k0 = jnp.argmax(maybe)
        k1 = jnp.where(jnp.any(sure), jnp.argmax(sure), N - 1)
        idx = jnp.clip(k0 + jnp.arange(size), 0, N - 1)
        sig_w = sig_fn(idx)
        above = sure.at[idx].set(sig_w >= thr)
        above = jnp.where(jnp.any(maybe), above, jnp.zeros_like(above))
        overflow = jnp.any(maybe) & (k1 - k0 + 1 > size)
        sig = None
    k = jnp.argmax(above)
    w = _threshold_crossing(jnp.maximum(k - 1, 0), k, thr, interp, lw, kernels)
    w = jnp.where(~jnp.any(above), jnp.inf, jnp.where(k == 0, 0.0, w))
    return w, overflow, sig


def _last_crossing(sig, thr, interp, lw, kernels):
    """Refined highest ω where σ̄(S) < ``thr`` (the end of the last sub-threshold stretch;
    the paper's literal bandwidth): inf if below at the last point, 0 if never below."""
    N = sig.shape[0]
    below = sig < thr
    j = N - 1 - jnp.argmax(below[::-1])
    w = _threshold_crossing(j, jnp.minimum(j + 1, N - 1), thr, interp, lw, kernels)
    return jnp.where(~jnp.any(below), 0.0, jnp.where(j == N - 1, jnp.inf, w))


def _sigma_of_S(L, kernels):
    n = L.shape[-1]
    IL = L + jnp.eye(n, dtype=L.dtype)
    _, S = _det_inv(IL, kernels)
    return _sigma_exact(S, kernels)


def _sigma_of_T(L, kernels, kind):
    n = L.shape[-1]
    eye = jnp.eye(n, dtype=L.dtype)
    _, S = _det_inv(L + eye, kernels)
    M = eye - S if kind == "T" else 2.0 * S - eye  # T = I − S; S − T = 2S − I
    return _sigma_exact(M, kernels)


def _peak(M_grid, L, interp, lw, kind, size, exact_all, kernels):
    """Refined maximum over ω of σ̄(M), M = T or S − T: (value, omega, overflow)."""
    N = L.shape[0]
    if exact_all:
        sig = _sigma_exact(M_grid, kernels)
        kpk = jnp.argmax(sig)
        vpk = sig[kpk]
        overflow = jnp.asarray(False)
    else:
        lo, hi = K.sigma_bounds(K.to_entries(M_grid))
        W = min(size, N)
        start = jnp.clip(jnp.argmax(lo) - W // 2, 0, N - W)
        idx = start + jnp.arange(W)
        sig = _sigma_exact(M_grid[idx], kernels)
        j = jnp.argmax(sig)
        kpk, vpk = idx[j], sig[j]
        # points outside the window that could exceed the peak found in it: exact too
        outside = (jnp.arange(N) < start) | (jnp.arange(N) >= start + W)
        idx2, count = _gather(outside & (hi > vpk), W)
        sig2 = jnp.where(jnp.arange(W) < count, _sigma_exact(M_grid[idx2], kernels), -jnp.inf)
        j2 = jnp.argmax(sig2)
        better = sig2[j2] > vpk
        kpk, vpk = jnp.where(better, idx2[j2], kpk), jnp.where(better, sig2[j2], vpk)
        overflow = count > W
    # golden-section search on [x_{k-1}, x_{k+1}] (piecewise-cubic L between the nodes)
    a = lw[jnp.maximum(kpk - 1, 0)]
    b = lw[jnp.minimum(kpk + 1, N - 1)]

    def val(x):
        x = jnp.atleast_1d(x)
        return _sigma_of_T(interp(interp.interval(x), x), kernels, kind)

    gr = (np.sqrt(5.0) - 1.0) / 2.0
    c = b - gr * (b - a)
    d = a + gr * (b - a)

    def body(_, s):
        a, b, c, d, fc, fd = s
        left = fc >= fd
        a2 = jnp.where(left, a, c)
        b2 = jnp.where(left, d, b)
        c2 = jnp.where(left, b2 - gr * (b2 - a2), d)
        d2 = jnp.where(left, c, a2 + gr * (b2 - a2))
        x_new = jnp.where(left, c2, d2)
        f_new = val(x_new)[0]
        fc2 = jnp.where(left, f_new, fd)
        fd2 = jnp.where(left, fc, f_new)
        return a2, b2, c2, d2, fc2, fd2

    fcd = val(jnp.stack([c, d]))
    s = jax.lax.fori_loop(0, _GOLDEN_ITERS, body, (a, b, c, d, fcd[0], fcd[1]))
    xm = jnp.where(s[4] >= s[5], s[2], s[3])
    vm = jnp.maximum(s[4], s[5])
    better = vm > vpk
    return jnp.where(better, vm, vpk), jnp.where(better, jnp.exp(xm), jnp.exp(lw[kpk])), overflow


def _loci_intervals(L, omega, spec, size, exact_all):
    """Paired loci at the ends of the intervals that need them: (idx, valid, a, b, overflow)."""
    N = L.shape[0]
    if exact_all:
        idx = jnp.arange(N - 1)
        valid = jnp.ones(N - 1, dtype=bool)
        overflow = jnp.asarray(False)
    else:
        c, r = K.eig_disc(K.to_entries(L))
        r = r * (1.0 + 1e-9) + 1e-12 * (1.0 + jnp.abs(c))
        ca, cb, ra, rb = c[:-1], c[1:], r[:-1], r[1:]
        one = 1.0 + c
        d1 = jnp.abs(one)
        alpha = jnp.where(
            d1 > r, jnp.arcsin(jnp.clip(r / jnp.where(d1 > 0, d1, 1.0), 0.0, 1.0)), jnp.inf
        )
        dth = jnp.abs(jnp.angle(one[1:] / one[:-1]))
        sus = ~(dth + alpha[:-1] + alpha[1:] < spec.max_phase_step * (1.0 - 1e-9))
        if spec.margins:
            ma, mb = jnp.abs(ca), jnp.abs(cb)
            gain = ((ma + ra >= 1.0) & (mb - rb < 1.0)) | ((ma - ra < 1.0) & (mb + rb >= 1.0))
            ia, ib = jnp.imag(ca), jnp.imag(cb)
            ph = ((ia + ra >= 0) & (ib - rb < 0)) | ((ia - ra < 0) & (ib + rb >= 0))
            ph = ph & ((jnp.real(ca) - ra < 0) | (jnp.real(cb) - rb < 0))
            sus = sus | gain | ph
        sus = sus | ~jnp.isfinite(ra) | ~jnp.isfinite(rb)
        idx, count = _gather(sus, min(size, N - 1))
        valid = jnp.arange(idx.shape[0]) < count
        overflow = count > idx.shape[0]
    ends = jnp.concatenate([idx, idx + 1])
    e = jnp.linalg.eigvals(L[ends])  # the only LAPACK call: a few matrices, or the fallback
    a, b = e[: idx.shape[0]], e[idx.shape[0] :]
    b = _pair(a, b)
    return idx, valid, a, b, overflow


def _refine_loci(idx, valid, a, b, interp, lw, kind, kernels):
    """Refined worst margin of ``kind`` ("gm"/"pm"): (value, omega)."""
    C, n = a.shape
    if kind == "gm":
        ok, _, grid_val = phase_crossing(a, b)
        f_of = jnp.imag
    else:
        ok, _, grid_val = gain_crossing(a, b)

        def f_of(lam):
            return jnp.log(jnp.abs(lam))

    ok = ok & valid[:, None]
    score = jnp.where(ok, jnp.abs(grid_val), jnp.inf).ravel()
    nr = min(_N_REFINE, score.shape[0])
    sel = jnp.argsort(score)[:nr]
    ci, li = sel // n, sel % n
    k = idx[ci]
    la, lb = a[ci, li], b[ci, li]
    sel_ok = jnp.isfinite(score[sel])

    def eig_at(t):
        x = lw[k] + t * (lw[k + 1] - lw[k])
        Lm = interp(k, x)
        guess = la + t * (lb - la)
        return K.eig_newton(K.to_entries(Lm), guess)

    def f(t):
        return f_of(eig_at(t))

    fa, fb = f_of(la), f_of(lb)
    ts = _illinois(f, fa, fb)
    lam = eig_at(ts)
    w = jnp.exp(lw[k] + ts * (lw[k + 1] - lw[k]))
    if kind == "gm":
        val = -_DB * jnp.log(jnp.abs(lam))
        sel_ok = sel_ok & (jnp.real(lam) < 0)
    else:
        val = _pm_deg(lam)
    val = jnp.where(sel_ok, val, jnp.inf)
    j = jnp.argmin(jnp.abs(val))
    return val[j], jnp.where(sel_ok[j], w[j], jnp.nan)


def _metrics(P, G, omega, p_ol, L_fn, spec: MetricsSpec, exact_all: bool):
    kern = spec.kernels
    N, n, _ = P.shape
    size = spec.n_candidates
    L = jnp.einsum("wij,wjk->wik", P, G)
    eye = jnp.eye(n, dtype=L.dtype)
    IL = L + eye
    det, S = _det_inv(IL, kern, unroll=True)
    lw = jnp.log(omega)
    interp = _Interp(L, lw, L_fn)
    nan = jnp.asarray(jnp.nan)
    overflow = jnp.asarray(False)

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
    ks = min(N, 256) if exact_all else 4
    ia, ca = _gather(amb, ks)
    s2 = _sigma_exact(jnp.concatenate([S[ia], IL[ia]]), kern)
    sS, sIL = s2[:ks], s2[ks:]
    s_amb = jnp.isfinite(sS) & (1.0 / sS <= rtol * jnp.maximum(1.0, sIL)) & (jnp.arange(ks) < ca)
    sing_k = finite_IL & sure
    sing_k = sing_k.at[ia].set(sing_k[ia] | s_amb)
    if not exact_all:
        overflow = overflow | (ca > ks)
    singular = jnp.any(sing_k)

    n_enc, _, resolved = nyquist_encirclements(det, spec.max_phase_step)
    p_ol = jnp.asarray(p_ol, dtype=jnp.float64)

    # --- loci where needed: resolution of every 1 + λ_i, margins ------------------------------
    idx, valid, la, lb, ovl = _loci_intervals(after(L, det), omega, spec, size, exact_all)
    overflow = overflow | ovl
    dphi = jnp.abs(jnp.angle((1.0 + lb) / (1.0 + la)))
    loci_ok = ~jnp.any(valid[:, None] & ~(dphi < spec.max_phase_step))
    resolved = resolved & loci_ok
    stable = nyquist_verdict(n_enc, p_ol, resolved, singular)

    out = dict(
        stable=stable,
        n_encirclements=n_enc,
        n_closed_loop_rhp=n_enc + p_ol,
        singular=singular,
        nyquist_resolved=resolved,
        iso_bandwidth_hz=nan,
        gm_db=nan,
        gm_freq_hz=nan,
        pm_deg=nan,
        pm_freq_hz=nan,
        t_peak_db=nan,
        t_peak_hz=nan,
        disk_margin=nan,
        iso_bandwidth_literal_hz=nan,
        disk_gm_db=nan,
        disk_pm_deg=nan,
    )
    if spec.margins:
        g, gw = _refine_loci(idx, valid, la, lb, interp, lw, "gm", kern)
        p, pw = _refine_loci(idx, valid, la, lb, interp, lw, "pm", kern)
        out.update(gm_db=g, gm_freq_hz=gw / TWO_PI, pm_deg=p, pm_freq_hz=pw / TWO_PI)

    sig_S_all = None
    if spec.bandwidth:
        lo, hi = K.sigma_bounds(K.to_entries(S))
        bw, ovb, sig_S_all = _first_crossing(
            lambda i: _sigma_exact(S[i], kern),
            lo,
            hi,
            ISO_THRESHOLD,
            interp,
            lw,
            size,
            exact_all,
            kern,
        )
        overflow = overflow | ovb
        out["iso_bandwidth_hz"] = jnp.where(stable, bw / TWO_PI, nan)
    if spec.t_peak:
        v, w, ovp = _peak(eye - S, L, interp, lw, "T", size, exact_all, kern)
        overflow = overflow | ovp
        out["t_peak_db"] = jnp.where(stable, _DB * jnp.log(v), nan)
        out["t_peak_hz"] = jnp.where(stable, w / TWO_PI, nan)
    if spec.disk:
        v, _, ovd = _peak(2.0 * S - eye, L, interp, lw, "SmT", size, exact_all, kern)
        overflow = overflow | ovd
        out["disk_margin"] = jnp.where(stable, 2.0 / v, 0.0)
        dm = disk_margin_from_peak(v)
        out["disk_gm_db"] = jnp.where(stable, dm["disk_gm_db"], 0.0)
        out["disk_pm_deg"] = jnp.where(stable, dm["disk_pm_deg"], 0.0)
    if spec.literal:
        if sig_S_all is None:
            sig_S_all = _sigma_exact(S, kern)
        lit = _last_crossing(sig_S_all, ISO_THRESHOLD, interp, lw, kern)
        out["iso_bandwidth_literal_hz"] = jnp.where(stable, lit / TWO_PI, nan)
    if spec.arrays:
        from ._nyquist import characteristic_loci

        if spec.full_sv:
            sv = jnp.linalg.svd(after(S, out["stable"]), compute_uv=False)
        else:
            sv = sig_S_all if sig_S_all is not None else _sigma_exact(S, kern)
        out.update(freq_hz=omega / TWO_PI, sv_T_minus_I=sv, loci=characteristic_loci(after(L, sv)))
    return out, overflow


def _check(P, G, omega):
    P, G, omega = loop_arrays(P, G, omega, "loop_metrics")
    if P.shape[0] < 2:
        raise ValueError("loop_metrics: at least 2 frequencies are needed")
    return P, G, omega


def metrics_screened(P, G, omega, p_ol, L_fn, spec):
    """The screened analysis: ``(fields dict, overflow)``; pure, jit/vmap-able. When
    ``overflow`` is true the result must be replaced by :func:`metrics_exact`'s."""
    return _metrics(P, G, omega, p_ol, L_fn, spec, exact_all=False)


def metrics_exact(P, G, omega, p_ol, L_fn, spec):
    """Every grid point exact (the fallback; same rules, no screen)."""
    return _metrics(P, G, omega, p_ol, L_fn, spec, exact_all=True)[0]


@eqx.filter_jit
def _screened_jit(P, G, omega, p_ol, L_fn, spec):
    return metrics_screened(P, G, omega, p_ol, L_fn, spec)


@eqx.filter_jit
def _exact_jit(P, G, omega, p_ol, L_fn, spec):
    return metrics_exact(P, G, omega, p_ol, L_fn, spec)


def _loop_metrics(P, G, omega, p_ol, L_fn, spec):
    if isinstance(P, jax.core.Tracer) or isinstance(p_ol, jax.core.Tracer):
        out, overflow = metrics_screened(P, G, omega, p_ol, L_fn, spec)
        res = jax.lax.cond(
            overflow, lambda: metrics_exact(P, G, omega, p_ol, L_fn, spec), lambda: out
        )
        return LoopMetrics(**res, exact_fallback=overflow)
    out, overflow = _screened_jit(P, G, omega, p_ol, L_fn, spec)
    if bool(overflow):  # the screen did not decide: the whole grid exactly (compiled on demand)
        out = _exact_jit(P, G, omega, p_ol, L_fn, spec)
    return LoopMetrics(**out, exact_fallback=jnp.asarray(overflow))


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

    Returns :class:`LoopMetrics`. Called on arrays it runs two jit-compiled programs (the
    screened one; the exact one only when the screen did not decide); called under ``jit``/
    ``vmap`` both are traced and joined by ``lax.cond`` (a ``select`` when vmapped).
    """
    P, G, omega = _check(P, G, omega)
    if spec.kernels not in ("xla", "lapack"):
        raise ValueError(f"MetricsSpec.kernels must be 'xla' or 'lapack', got {spec.kernels!r}")
    return _loop_metrics(P, G, omega, jnp.asarray(p_ol, dtype=jnp.float64), L_fn, spec)
