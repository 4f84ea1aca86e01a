"""The per-chunk compute path of :func:`hapid.uncertainty.robust_check`: the loop figures
(``RobustReport`` fields, arrays over the chunk's plants) of a chunk of plants ``P (S, N, n, n)``
with their open-loop RHP pole counts ``p_ol (S,)``, one controller ``G (N, n, n)`` on ω
(rad/s).

Compute path: every plant is analysed by
:func:`hapid.control.loop_metrics`'s program (XLA small-matrix kernels for det/inverse/σ̄ and
the eigenvalues of the loci, no LAPACK inside; exact values only where the cheap bounds do
not decide; refined crossings) in its two passes (:mod:`hapid.control._metrics`): the
grid pass (every frequency) once per plant — the plain jitted program, no ``vmap``, the plants
side by side on a thread per core — and the
refinement pass (a few small sequential root-finding steps per plant) once per chunk of
``chunk`` plants, ``vmap``-ed, so its step count is paid once per chunk instead of once per
plant (``vectorize=False``, the default); or the whole analysis ``vmap``-ed over chunks
(``vectorize=True``; the last chunk padded, ``p_ol`` an array: one compile). The grid pass
per plant is the faster: under ``vmap`` the batch axis sits in front of the kernels'
entry-major ``(n, n, N)`` layout (timings: benchmarks/README.md, "Per-plant program, not
vmap"). Same verdicts as the LAPACK reference loop analysis of the tests
(``tests/oracle_loop.py``; benchmarks/bench_fast.py, tests/test_control_metrics.py).
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._aot import cached_jit
from ..control import MetricsSpec
from ..control._metrics import grid_pass, metrics_screened, refine_many


def _spec(metrics: tuple) -> MetricsSpec:
    """The :class:`~hapid.control.MetricsSpec` of a robust check: verdict, bandwidth and
    margins always; the peak of σ̄(T) and the disk margin when ``metrics`` asks for them."""
    return MetricsSpec(bandwidth=True, margins=True, t_peak="t_peak" in metrics,
                       disk="disk" in metrics)  # fmt: skip


def _fields(m: dict, spec: MetricsSpec) -> dict:
    keys = ("stable", "n_closed_loop_rhp", "nyquist_resolved", "gm_db", "pm_deg",
            "iso_bandwidth_hz", "gm_freq_hz", "pm_freq_hz")  # fmt: skip
    out = {k: m[k] for k in keys}
    nan = jnp.full_like(m["gm_db"], jnp.nan)
    out["t_peak_db"] = m["t_peak_db"] if spec.t_peak else nan
    if spec.disk:  # loop_metrics fills the disk margin's GM/PM (0 when not stable)
        out |= {k: m[k] for k in ("disk_margin", "disk_gm_db", "disk_pm_deg")}
    else:
        out["disk_margin"] = out["disk_gm_db"] = out["disk_pm_deg"] = nan
    return out


@eqx.filter_jit
def _metrics_chunk(P, p_ol, G, omega, spec):
    def one(P_, p_):
        return _fields(metrics_screened(P_, G, omega, p_, None, spec), spec)

    return jax.vmap(one)(P, p_ol)


def grid_pass_one(P, i, p_ol, G, omega, spec):
    """The grid pass of plant ``i`` of a chunk (the chunk stays on the device: no slice is
    dispatched from Python)."""
    return grid_pass(P[i], G, omega, p_ol[i], spec)


# through the export cache (hapid._aot): a later process skips tracing and lowering them
_grid_one = cached_jit(grid_pass_one)


def refine_chunk(grids, spec):
    """The refinement pass of every plant of a chunk at once (vmapped: its sequential steps
    are shared by the chunk instead of paid per plant)."""
    out, tasks = jax.tree.map(lambda *x: jnp.stack(x), *grids)
    return _fields(refine_many(out, tasks, None, spec), spec)


_refine_chunk = cached_jit(refine_chunk)


@functools.cache
def _pool() -> ThreadPoolExecutor:
    """Threads that run the per-plant grid passes side by side, one per core this process may
    use: each pass is one single-threaded XLA:CPU program (no LAPACK call, so no concurrent
    LAPACK kernels), and the plants are independent, so the results are those of a serial loop
    (timings: benchmarks/README.md, "The route after the redesign, on a slower machine")."""
    cores = (
        os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else range(os.cpu_count() or 1)
    )
    return ThreadPoolExecutor(max(1, len(cores)), thread_name_prefix="hapid-grid")


def _analyze_chunk(P, p_ol, G, omega, vectorize, spec, m=None):
    """Per-plant fields of a (padded) chunk: :func:`~hapid.control.loop_metrics`'s program
    vmapped over the chunk (``vectorize=True``), or its grid pass once per plant and its
    refinement pass vmapped over the chunk (default). ``m``: the chunk's real plants (the
    rest is padding; default all): the per-plant grid pass skips the padding, whose
    refinement repeats the last real plant's."""
    if vectorize:
        return {k: np.asarray(v) for k, v in _metrics_chunk(P, p_ol, G, omega, spec).items()}
    # the grid pass per plant, not vmapped: a vmapped program keeps the batch axis in front
    # of the kernels' entry-major layout (measured ~2-3x slower per plant); the refinement
    # is a few small sequential steps, whose cost is their count, so it is shared
    size = P.shape[0]
    m = size if m is None else int(m)

    def one(i):
        return _grid_one(P, np.asarray(i, np.int32), p_ol, G, omega, spec)

    first = one(0)  # alone: the program is loaded (or compiled) once, not by two threads
    grids = [first, *_pool().map(one, range(1, m))]
    grids += [grids[-1]] * (size - m)
    return {k: np.asarray(v) for k, v in _refine_chunk(grids, spec).items()}


def _pad(x, size):
    """Pad the leading axis to ``size`` with copies of the last row (no recompile for the
    last chunk)."""
    m = x.shape[0]
    if m == size:
        return x
    return jnp.concatenate([x, jnp.broadcast_to(x[-1:], (size - m,) + x.shape[1:])])
