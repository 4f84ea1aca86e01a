"""Drive an optimistix solver with one extra, scipy-style stopping rule (cost stagnation).

Why not ``optx.least_squares``: near an optimum whose cost is flat to rounding (a matrix on
the PSD boundary, e.g. a mechanism with no stiffness, makes the cost quartic in its Cholesky
factor), optimistix's trust region keeps rejecting steps whose predicted decrease is below
rounding, and its Cauchy test only counts accepted steps — so Levenberg–Marquardt ran to
``max_steps`` (3000 measured) at a cost already constant to 8 digits after ~25 steps. This
loop uses the solver's own ``init``/``step``/``terminate`` (the documented
``AbstractLeastSquaresSolver``/``AbstractMinimiser`` interface) and also stops when the cost
has not decreased by a relative ``ftol`` over ``patience`` consecutive steps (scipy's
``ftol`` idea). Either criterion counts as converged — a stall only while the cost is
flat: if the last iterate's cost is above the best seen by more than ``ftol`` (a diverging
Gauss–Newton, measured at cost 1e29 after a stall), the status is *failed* and the best
iterate is returned, never the diverged one.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jax import lax
from jaxtyping import Array

from ._result import CONVERGED, FAILED, MAX_STEPS


def iterate(
    solver,
    fn: Callable,
    cost: Callable[[Array], Array],
    y0: Array,
    *,
    max_steps: int,
    ftol: float,
    patience: int,
    stall: bool = True,
) -> tuple[Array, Array, Array]:
    """Run ``solver`` on ``fn(y, args) -> (out, aux)`` from ``y0``.

    ``cost(y)`` is the scalar objective used for the stagnation rule (``stall=False``
    switches the rule off: line-search minimisers). Returns
    ``(y, n_steps, status_code)`` (0 converged, 1 max steps, 2 failed/non-finite).
    """
    args, options, tags = None, {}, frozenset()
    f_struct, aux_struct = jax.eval_shape(lambda: fn(y0, args))
    state0 = solver.init(fn, y0, args, options, f_struct, aux_struct, tags)
    term0, result0 = solver.terminate(fn, y0, args, options, state0, tags)
    dyn0, static = eqx.partition(state0, eqx.is_array)
    c0 = cost(y0)
    carry0 = (y0, jnp.array(0), dyn0, term0, result0, c0, jnp.array(0), jnp.array(False), y0, c0)

    def cond(carry):
        _, k, _, term, result, _, _, stalled, _, _ = carry
        return (~term) & (~stalled) & (result == optx.RESULTS.successful) & (k < max_steps)

    def body(carry):
        y, k, dyn, _, _, ref, since, _, y_best, c_best = carry
        state = eqx.combine(static, dyn)
        new_y, new_state, _ = solver.step(fn, y, args, options, state, tags)
        term, result = solver.terminate(fn, y, args, options, new_state, tags)
        finite = jnp.all(jnp.isfinite(new_y))
        result = optx.RESULTS.where(finite, result, optx.RESULTS.nonfinite)
        c = cost(new_y)
        improved = c < ref * (1.0 - ftol)
        ref = jnp.where(improved, c, jnp.minimum(ref, c))
        since = jnp.where(improved, 0, since + 1)
        better = jnp.isfinite(c) & (c < c_best)
        y_best = jnp.where(better, new_y, y_best)
        c_best = jnp.where(better, c, c_best)
        new_dyn, _ = eqx.partition(new_state, eqx.is_array)
        return (new_y, k + 1, new_dyn, term, result, ref, since, stall & (since >= patience),
                y_best, c_best)  # fmt: skip

    y, k, _, term, result, _, _, stalled, y_best, c_best = lax.while_loop(cond, body, carry0)
    c_last = cost(y)
    diverged = ~(c_last <= c_best * (1.0 + 10.0 * ftol) + 1e-300)
    ok = (term | stalled) & (result == optx.RESULTS.successful) & ~(stalled & ~term & diverged)
    y = jnp.where(stalled & diverged, y_best, y)
    maxed = (result == optx.RESULTS.nonlinear_max_steps_reached) | (
        (result == optx.RESULTS.successful) & ~ok
    )
    maxed = maxed & ~(stalled & ~term & diverged)
    code = jnp.where(ok, CONVERGED, jnp.where(maxed, MAX_STEPS, FAILED))
    return y, k, code
