# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""The one place hapid touches jaxopt (a cross-check backend that can be dropped).

jaxopt is no longer developed upstream (docs/conventions.md, "Solvers"); :class:`JaxoptLM` (the
solver object the fits take) and :func:`jaxopt_lm` are the whole interface, jaxopt imported
lazily (CLI start-up).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..defaults import NLS_ATOL, NLS_RTOL


class JaxoptLM(eqx.Module):
    """jaxopt's Levenberg–Marquardt as a fit solver (``hapid.fit.fit_nls(frf,
    solver=JaxoptLM())``; a cross-check of the optimistix default). Stops (Madsen–Nielsen)
    when ``‖Δθ‖₂ ≤ rtol(‖θ‖₂ + rtol)`` or ``‖Jᵀr‖∞ ≤ atol`` (scaled units); normal equations
    solved by Cholesky. ``rtol``, ``atol``: floats or scalar arrays."""

    rtol: float = NLS_RTOL
    atol: float = NLS_ATOL

    def run(self, residual_fn, theta0, max_steps: int):
        """``(theta, n_steps, status_code)`` of :func:`jaxopt_lm` with these tolerances
        (``max_steps`` a python int: jaxopt's loop bound is static)."""
        return jaxopt_lm(residual_fn, theta0, max_steps=max_steps, rtol=self.rtol, atol=self.atol)


def jaxopt_lm(
    residual_fn: Callable[[Array], Array],
    theta0: Float[Array, " p"],
    *,
    max_steps: int,
    rtol: float,
    atol: float,
) -> tuple[Float[Array, " p"], Int[Array, ""], Int[Array, ""]]:
    """Minimize ``½‖residual_fn(θ)‖²`` with ``jaxopt.LevenbergMarquardt``.

    Stops (Madsen–Nielsen) when ``‖Δθ‖₂ ≤ rtol(‖θ‖₂ + rtol)`` or ``‖Jᵀr‖∞ ≤ atol``; normal
    equations solved by Cholesky. Returns ``(theta, n_steps, status_code)`` with status 0
    converged, 1 max steps, 2 non-finite.
    """
    try:
        with warnings.catch_warnings():  # "JAXopt is no longer maintained": known, see above
            warnings.simplefilter("ignore", DeprecationWarning)
            import jaxopt  # local: CLI start-up (jaxopt, ~0.3 s)
    except ImportError as e:  # pragma: no cover - jaxopt is a declared dependency
        raise ValueError("JaxoptLM needs jaxopt, which is not installed") from e
    lm = jaxopt.LevenbergMarquardt(
        residual_fun=residual_fn,
        maxiter=max_steps,
        stop_criterion="madsen-nielsen",
        xtol=rtol,
        gtol=atol,
        solver="cholesky",
        implicit_diff=False,
        materialize_jac=True,
        jit=True,
    )
    theta, state = lm.run(theta0)
    n_steps = jnp.asarray(state.iter_num)
    finite = jnp.all(jnp.isfinite(theta))
    code = jnp.where(~finite, 2, jnp.where(n_steps >= max_steps, 1, 0))
    return theta, n_steps, code
