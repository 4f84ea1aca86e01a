# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Loop metrics that compute only what is asked, with crossings refined off the grid.

:func:`loop_metrics` decides stability by the same rules as the LAPACK reference loop
analysis of the tests (``tests/oracle_loop.py``, its independent check): generalized
Nyquist on ``det(I + L)`` with ``P_ol`` = open-loop RHP poles of plant *and* controller,
the grid resolution check of ``det(I + L)`` and of every characteristic locus ``1 + λ_i``,
and the singularity check ``σ̲(I + L) ≤ rtol · max(1, σ̄(I + L))``. It differs in how much
it computes:

* ``det(I + L)`` and ``S = (I + L)⁻¹`` by the XLA kernels of :mod:`._kernels` (no LAPACK);
* σ̄ of ``S``, ``T`` (and ``S − T``) is *bounded* cheaply at every frequency and computed
  exactly (Jacobi on ``AᴴA``) only where the bounds do not decide — around the first
  crossing of ``1 − 1/√2`` and around the peaks;
* eigenvalues of ``L`` (the loci) by the XLA QR kernel (:func:`._kernels.eigvals`:
  Hessenberg + Wilkinson-shifted QR, no LAPACK), paired between neighbouring frequencies by
  the reference tracker's rule (optimal permutation, by dynamic programming over subsets:
  :func:`._kernels.pair_optimal`) — only on the grid intervals where a disc that provably
  holds every eigenvalue (centre ``tr L/n``, radius ``‖L − tr L/n·I‖_F``) leaves the loci
  rules anything to decide (:func:`._metrics_loci._loci_screen`; where the model is right
  the loci cluster about ``g`` and most intervals are left out);
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

This module is the entry point (:func:`loop_metrics`, :func:`metrics_screened`); the parts:
:mod:`._metrics_spec` (:class:`MetricsSpec`, :class:`LoopMetrics`), :mod:`._metrics_grid`
and :mod:`._metrics_refine` (the passes), :mod:`._metrics_sigma` (σ̄ of ``S``, ``T``),
:mod:`._metrics_loci` (the loci), :mod:`._metrics_local` (the loop near one interval, the
Illinois root finder).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from .._aot import cached_jit
from ._loop import loop_arrays
from ._metrics_grid import grid_pass as grid_pass
from ._metrics_refine import refine_many as refine_many
from ._metrics_refine import refine_pass as refine_pass
from ._metrics_spec import ISO_THRESHOLD as ISO_THRESHOLD
from ._metrics_spec import TWO_PI as TWO_PI
from ._metrics_spec import LoopMetrics as LoopMetrics
from ._metrics_spec import MetricsSpec as MetricsSpec


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
    spec: MetricsSpec = MetricsSpec(),  # noqa: B008  (a frozen dataclass: immutable)
    L_fn: Callable | None = None,
) -> LoopMetrics:
    """Verdict and the metrics ``spec`` asks for of the loop ``L = P G`` (negative feedback).

    Args:
        P, G: plant and controller responses ``(N, n, n)`` complex on ``omega``.
        omega: increasing positive frequencies (rad/s), ``(N,)``; it must reach the loop's
            real end values and resolve the phase of ``det(I + L)`` (see
            :func:`~hapid.control.nyquist_encirclements`).
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
