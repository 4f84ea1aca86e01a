"""Sequencing of LAPACK calls inside one XLA program (a jaxlib 0.10.2 CPU deadlock).

Observed on a 2-core machine: when two batched LAPACK kernels (e.g. the LU of ``solve``/
``det`` and the ``eig`` of the loci) run concurrently in one jitted, vmapped program, both
wait in ``jax::ParallelBatchMap`` for workers of the shared intra-op thread pool and the
process hangs with the CPU idle (gdb: ``LuDecompositionKernel`` and
``EigenvalueDecompositionComplexKernel`` each blocked in ``BlockingCounter::Wait``). Each
kernel alone is fine. :func:`after` makes a value depend on others through
``lax.optimization_barrier`` so the LAPACK calls of this package run one after the other.
"""

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl


def after(x, *deps):
    """``x``, but only available once every array in ``deps`` has been computed."""
    return jax.lax.optimization_barrier((x, deps))[0]


def lu_det_solve(A, B):
    """``det(A)`` and ``A⁻¹ B`` from a single LU factorization (batched over leading axes)."""
    lu, piv = jsl.lu_factor(A)
    n = A.shape[-1]
    swaps = jnp.sum(piv != jnp.arange(n, dtype=piv.dtype), axis=-1)
    sign = jnp.where(swaps % 2 == 0, 1.0, -1.0)
    det = sign * jnp.prod(jnp.diagonal(lu, axis1=-2, axis2=-1), axis=-1)
    if A.ndim == 2:
        X = jsl.lu_solve((lu, piv), B)
    else:
        X = jax.vmap(lambda l_, p_, b_: jsl.lu_solve((l_, p_), b_))(
            lu.reshape((-1, n, n)), piv.reshape((-1, n)), B.reshape((-1,) + B.shape[-2:])
        ).reshape(B.shape)
    return det, X
