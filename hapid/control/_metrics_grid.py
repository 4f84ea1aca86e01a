"""The grid pass of :func:`~hapid.control.loop_metrics` (every grid frequency): the verdict,
and for each asked metric the grid interval to refine with a window of grid nodes around it
(``_windows``), handed to the refinement pass (:mod:`._metrics_refine`)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from . import _kernels as K
from ._lapack import after
from ._metrics_local import _windows
from ._metrics_loci import _loci_candidates, _loci_pairs
from ._metrics_sigma import _det_inv, _fill_where, _first_above, _peak_grid, _sigma_exact
from ._metrics_spec import ISO_THRESHOLD, TWO_PI, MetricsSpec
from ._nyquist import characteristic_loci, nyquist_encirclements, nyquist_verdict


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
        if spec.full_sv:
            sv = jnp.linalg.svd(after(S, stable), compute_uv=False)
        else:
            sv = sig_S_all
        out.update(freq_hz=omega / TWO_PI, sv_T_minus_I=sv, loci=characteristic_loci(after(L, sv)))
    return out, tasks
