"""The solvers of :func:`~hapid.fit.fit_nls` and :func:`~hapid.fit.fit_ml`, as objects.

A fit takes its solver as an object (as optimistix does), not as a name plus options:

- an optimistix least-squares solver (``optx.LevenbergMarquardt``, ``optx.Dogleg``,
  ``optx.GaussNewton``, …), run on the residual ``r(θ)``;
- an optimistix minimiser (``optx.BFGS``, ``optx.NonlinearCG``, …), run on the cost
  ``½‖r(θ)‖²``;
- :class:`~hapid.fit.JaxoptLM`, jaxopt's Levenberg–Marquardt (a cross-check backend).

The object's ``rtol`` and ``atol`` are its Cauchy tolerances (on θ and on the residuals, in
scaled units). The default, :data:`DEFAULT_SOLVER`, is Levenberg–Marquardt on the Cholesky
normal equations with the tolerances of :mod:`hapid.defaults`. Names are the edges' (the CLI's
``--solver``, a scene's ``fit.solver``): :func:`solver_from` maps them, with the tolerances
and the linear solver, to objects in one place.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from ..defaults import NLS_ATOL, NLS_LINEAR_SOLVER, NLS_RTOL, NLS_SOLVER
from ._iterate import iterate
from ._jaxopt_adapter import JaxoptLM

LEAST_SQUARES_SOLVERS = {"lm": optx.LevenbergMarquardt, "dogleg": optx.Dogleg,
                         "gauss_newton": optx.GaussNewton}  # fmt: skip
"""The optimistix least-squares solvers by the name the CLI and the scenes use."""
MINIMISERS = {"bfgs": optx.BFGS, "nonlinear_cg": optx.NonlinearCG}
"""The optimistix minimisers of ``½‖r‖²`` by name."""
SOLVERS = (*LEAST_SQUARES_SOLVERS, *MINIMISERS, "jaxopt_lm")
"""Every solver name :func:`solver_from` accepts."""
LINEAR_SOLVERS = ("cholesky", "qr")
"""The linear-solver names of the least-squares solvers: ``"cholesky"`` (normal equations,
``lx.Normal(lx.Cholesky())``) or ``"qr"`` (``lx.QR()``, optimistix's default)."""

Solver = optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser | JaxoptLM


def _linear_solver(name: str) -> lx.AbstractLinearSolver:
    if name not in LINEAR_SOLVERS:
        raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS}, got {name!r}")
    return lx.Normal(lx.Cholesky()) if name == "cholesky" else lx.QR()


def solver_from(name: str = NLS_SOLVER, *, rtol=NLS_RTOL, atol=NLS_ATOL,
                linear_solver: str = NLS_LINEAR_SOLVER) -> Solver:  # fmt: skip
    """The solver object of a name in :data:`SOLVERS` with Cauchy tolerances ``rtol``,
    ``atol`` (floats or scalar arrays, traced ones too). ``linear_solver`` (one of
    :data:`LINEAR_SOLVERS`) applies to the least-squares solvers (``lm``, ``dogleg``,
    ``gauss_newton``); the minimisers have none and ``jaxopt_lm`` always uses Cholesky.
    Raises ``ValueError`` naming the allowed names for an unknown name or linear solver."""
    if name not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {name!r}")
    lin = _linear_solver(linear_solver)
    if name in LEAST_SQUARES_SOLVERS:
        return LEAST_SQUARES_SOLVERS[name](rtol=rtol, atol=atol, linear_solver=lin)
    if name in MINIMISERS:
        return MINIMISERS[name](rtol=rtol, atol=atol)
    return JaxoptLM(rtol=rtol, atol=atol)


DEFAULT_SOLVER = solver_from()
"""The fits' default solver: ``optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10,
linear_solver=lx.Normal(lx.Cholesky()))`` (:mod:`hapid.defaults`)."""


def solver_name(solver: Solver) -> str:
    """The label of ``solver`` in results and model files: its name in :data:`SOLVERS` when
    its class is one of those, else the class name."""
    for name, cls in (LEAST_SQUARES_SOLVERS | MINIMISERS | {"jaxopt_lm": JaxoptLM}).items():
        if type(solver) is cls:
            return name
    return type(solver).__name__


def check_solver(solver, what: str = "fit_nls", jaxopt: bool = True) -> None:
    """Raise ``ValueError`` unless ``solver`` is an optimistix least-squares solver or
    minimiser (or a :class:`JaxoptLM`, when ``jaxopt``); a string gets a pointer to
    :func:`solver_from`."""
    kinds = (optx.AbstractLeastSquaresSolver, optx.AbstractMinimiser)
    if isinstance(solver, kinds) or (jaxopt and isinstance(solver, JaxoptLM)):
        return
    hint = f" (for a name use hapid.fit.solver_from({solver!r}))" if isinstance(solver, str) else ""
    allowed = "an optimistix least-squares solver or minimiser" + (
        " or hapid.fit.JaxoptLM" if jaxopt else ""
    )
    raise ValueError(f"{what}: solver must be {allowed}, got {solver!r}{hint}")


def with_array_tolerances(solver: Solver) -> Solver:
    """``solver`` with ``rtol``, ``atol`` as float64 arrays, so that under ``jit`` they are
    traced (one compile serves every tolerance) and the rest of the solver is static."""
    return eqx.tree_at(
        lambda s: (s.rtol, s.atol),
        solver,
        (jnp.asarray(solver.rtol, jnp.float64), jnp.asarray(solver.atol, jnp.float64)),
    )


def is_default_lm(solver: Solver) -> bool:
    """``solver`` is :data:`DEFAULT_SOLVER` up to its tolerances (Levenberg–Marquardt on the
    Cholesky normal equations, optimistix's norm, trust region and verbosity): the solver
    :func:`hapid.fit._lm_batch.lm_compressed` reproduces step for step."""
    if type(solver) is not optx.LevenbergMarquardt:
        return False
    bare = lambda s: eqx.tree_at(lambda t: (t.rtol, t.atol), s, (0.0, 0.0))  # noqa: E731
    return bool(bare(solver) == bare(DEFAULT_SOLVER))


def run_solver(problem, theta0, solver: Solver, max_steps, ftol, patience):
    """Minimise ``½‖problem(θ)‖²`` from ``theta0`` with ``solver``: ``(theta, n_steps,
    status_code)`` (0 converged, 1 max steps, 2 failed). Least-squares solvers run on the
    residual with the stagnation rule (``ftol`` over ``patience`` steps,
    :func:`hapid.fit._iterate.iterate`); minimisers on ``problem.cost`` without it (their
    line searches have long runs of rejected trials early on, and their own Cauchy test on
    the scalar cost terminates); :class:`JaxoptLM` by its own Madsen–Nielsen test
    (``max_steps`` a python int)."""
    if isinstance(solver, JaxoptLM):
        return solver.run(problem, theta0, max_steps)
    if isinstance(solver, optx.AbstractLeastSquaresSolver):
        fn = lambda th, args: (problem(th), None)  # noqa: E731
        stall = True
    else:
        fn = lambda th, args: (problem.cost(th), None)  # noqa: E731
        stall = False
    return iterate(solver, fn, problem.cost, theta0, max_steps=max_steps, ftol=ftol,
                   patience=patience, stall=stall)  # fmt: skip
