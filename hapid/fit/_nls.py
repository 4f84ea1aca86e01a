# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""Nonlinear least-squares fit of PD hand and mechanism impedances (hapid's improvement).

The model is ``Ẑ_H = M_H s² + B_H s + K_H`` and ``Ẑ_T = Ẑ_M + Ẑ_H`` with all six matrices
symmetric PSD by construction (``hapid.fit._pd``). Residuals are the weighted complex errors
``w ⊙ (Ẑ − Z)`` of Z_H and Z_T jointly (real and imaginary parts stacked), optionally plus
the plant error ``w_P ⊙ (P̂ − P)`` with ``P = Z_H Z_T⁻¹``.

Weights (per element ``(i, j)`` and frequency ``ω``; std is the FRF's ``Z_*_std``, the std of
the complex estimate, real and imaginary parts together):

- ``"relative"`` (default): ``1/‖Z(jω)‖_F``, each frequency's error relative to the size of
  that frequency's data matrix (own norm for Z_H and Z_T).
- ``"paper"``: the paper's ``h(jω) = 1/(jω + ω_c)²``, normalized to unit DC gain and by
  ``z_ref`` (``ω_c²/((jω + ω_c)² z_ref)``) — the same minimizer as the paper's weights.
- ``"noise"``: ``√2/std``, so each real residual has unit variance (χ² cost).
- ``"blend"``: ``1/sqrt(std²/2 + (blend_floor·‖Z(jω)‖_F)²)``: noise weights with a relative
  model-error floor; tends to ``"noise"`` as ``blend_floor → 0``.

P residual weight: ``p_weight/‖P(jω)‖_F``.

Fit band. Only frequencies ``≤ f_max_hz`` enter (default 40 Hz: docs/conventions.md, "Weights and fit
band" — a measured device's Z_H, Z_T are far from second order above ~20 Hz, and relative
weights on data up to ~40 Hz gave the best P·P̂⁻¹ band over 1–30 Hz; use ``None`` for all
frequencies, e.g. on strictly second-order synthetic data). Out-of-band frequencies are
masked (zero residual) so shapes stay static under ``jit``/``vmap``.

Scaling. ``s`` is divided by ``ω_ref`` (geometric mean of the band's frequencies) and Z by
``z_ref`` (median magnitude of the band's Z_H and Z_T elements); ``theta`` lives in those
units (docs/conventions.md: the starting Jacobian's condition number dropped 15–40×).
"""

from __future__ import annotations

import inspect
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._linalg import pinv_psd
from ..defaults import FIT_BAND_HZ, NLS_MAX_STEPS
from ..frf import FRF
from ..impedance import ImpedanceModel
from ._compress import compress
from ._jaxopt_adapter import JaxoptLM
from ._lm_batch import covariance_batch, lm_compressed
from ._pd import (
    Scale,
    boundary_report,
    model_to_theta,
    project_pd,
    theta_to_model,
    theta_to_scaled,
)
from ._problem import Problem, _check_data, _warn_jacobian_size, make_problem
from ._result import CONVERGED, FAILED, NLSResult
from ._solvers import (
    DEFAULT_SOLVER,
    Solver,
    check_solver,
    is_default_lm,
    run_solver,
    solver_name,
    with_array_tolerances,
)
from ._wls import OMEGA_C_PAPER, wls


class LaplaceCovariance(NamedTuple):
    """The Laplace covariance of a least-squares fit at θ (:func:`laplace_covariance`), in the
    problem's scaled θ units; a pytree (jittable).

    - ``cov``: ``(p, p)``, ``σ̂²(JᵀJ)⁺``.
    - ``sigma2``: ``()``, the residual variance σ̂² (1 for noise weights, else ``2·cost/(m−p)``).
    - ``cost``: ``()``, ``½‖r‖²`` at θ.
    """

    cov: Float[Array, "p p"]
    sigma2: Float[Array, ""]
    cost: Float[Array, ""]


def laplace_covariance(
    problem: Problem, theta: Float[Array, " p"], noise_weights: bool, n_residuals=None
) -> LaplaceCovariance:
    """:class:`LaplaceCovariance` ``(σ̂²(JᵀJ)⁺, σ̂², cost)`` at ``theta``; σ̂² = 1 for noise
    weights else 2·cost/(m−p).

    ``n_residuals`` (default ``problem.n_residuals``) is ``m``: give the full problem's count
    when ``problem`` is its :class:`~hapid.fit._compress.CompressedProblem` (same JᵀJ, cost).
    """
    J = jax.jacfwd(problem)(theta)
    r = problem(theta)
    cost = 0.5 * jnp.sum(r**2)
    p = theta.shape[-1]
    m = problem.n_residuals if n_residuals is None else n_residuals
    dof = jnp.maximum(m - p, 1)
    sigma2 = jnp.asarray(1.0) if noise_weights else 2.0 * cost / dof
    return LaplaceCovariance(sigma2 * pinv_psd(J.T @ J), sigma2, cost)


def final_status(theta, cost, code) -> Array:
    """The solver's status code, ``FAILED`` when ``theta`` or ``cost`` is not finite."""
    finite = jnp.all(jnp.isfinite(theta)) & jnp.isfinite(cost)
    return jnp.where(finite, code, FAILED).astype(jnp.int32)


def absorb_eps(theta: Float[Array, " p"], n: int, eps) -> Float[Array, " p"]:
    """``theta`` of the matrices ``L Lᵀ + eps·I`` themselves (their Cholesky factors, positive
    diagonal; ``eps`` > 0), so that ``theta_to_model(θ, scale)`` with no eps is the model."""
    mats = theta_to_scaled(theta, n, eps)
    L = jnp.linalg.cholesky(0.5 * (mats + jnp.swapaxes(mats, -1, -2)))
    rows, cols = np.tril_indices(n)
    return L[:, rows, cols].reshape(-1)


def init_model(init, n: int, data: str = "FRF", what: str = "") -> ImpedanceModel:
    """A fit's starting model: an :class:`ImpedanceModel`, or an :class:`NLSResult`'s model,
    checked to have ``n`` rods (``data`` names what has them; ``what`` prefixes the errors)."""
    if isinstance(init, NLSResult):
        init = init.model
    if not isinstance(init, ImpedanceModel):
        raise ValueError(
            f"{what}init must be None, an ImpedanceModel or an NLSResult, got {type(init).__name__}"
        )
    if init.n != n:
        raise ValueError(f"{what}init has n = {init.n} rods but the {data} has n = {n}")
    return init


def _init_theta(frf: FRF, init, scale: Scale, omega_c, f_max_hz, init_floor):
    if init is None:
        init = wls(frf, omega_c=omega_c, f_max_hz=f_max_hz)
    init = init_model(init, frf.n)
    return model_to_theta(project_pd(init, floor=init_floor), scale, floor=init_floor)


@eqx.filter_jit
def _fit_core(frf, init, dyn, static):
    """The jitted fit. ``dyn`` holds numeric options as arrays and the solver (its tolerances
    arrays): one compile serves a sweep over them; ``static`` the structural options (weight,
    solver label, ...)."""
    weight, solver_label, use_P, throw, jaxopt_steps = static
    d = dyn
    problem = make_problem(
        frf,
        weight=weight,
        f_max_hz=d["f_max_hz"],
        omega_c=d["omega_c"],
        use_P_residual=use_P,
        blend_floor=d["blend_floor"],
        p_weight=d["p_weight"],
        pd_eps=d["pd_eps"],
    )
    theta0 = _init_theta(frf, init, problem.scale, d["omega_c"], d["f_max_hz"], d["init_floor"])
    max_steps = d["max_steps"] if jaxopt_steps is None else jaxopt_steps
    # without the P term the residual is linear in the matrices: the solver and the Laplace
    # covariance work on its exact 6-rows-per-element compression (same cost and JᵀJ)
    work = problem if use_P else compress(problem)
    theta, n_steps, code = run_solver(
        work, theta0, d["solver"], max_steps, d["ftol"], d["patience"]
    )
    cov, sigma2, cost = laplace_covariance(work, theta, weight == "noise", problem.n_residuals)
    free = theta  # the solver's L (matrices L Lᵀ + pd_eps·I)
    theta, G = jax.lax.cond(
        d["pd_eps"] > 0,
        lambda t: (
            absorb_eps(t, frf.n, d["pd_eps"]),
            jax.jacfwd(absorb_eps)(t, frf.n, d["pd_eps"]),
        ),
        lambda t: (t, jnp.eye(t.shape[-1], dtype=t.dtype)),
        free,
    )
    cov = G @ cov @ G.T
    code = final_status(theta, cost, code)
    if throw:
        theta = eqx.error_if(
            theta,
            code != CONVERGED,
            "fit_nls: the fit did not converge (status max_steps or failed)",
        )
    model = theta_to_model(theta, problem.scale)
    return NLSResult(
        model=model,
        theta=theta,
        scale=problem.scale,
        status_code=code,
        n_steps=jnp.asarray(n_steps).astype(jnp.int32),
        cost=cost,
        covariance=cov,
        sigma2=sigma2,
        n_residuals=problem.n_residuals,
        at_boundary=boundary_report(theta_to_model(free, problem.scale), rtol=d["boundary_rtol"]),
        weight=weight,
        solver=solver_label,
    )


#: fit_nls warns when its largest array (the dense P-residual Jacobian, or the compressed
#: residual's QR factors without the P term) exceeds this.
def fit_nls(
    frf: FRF,
    init: ImpedanceModel | NLSResult | None = None,
    *,
    weight: str = "relative",
    f_max_hz: float | None = FIT_BAND_HZ,
    omega_c: float = OMEGA_C_PAPER,
    solver: Solver = DEFAULT_SOLVER,
    use_P_residual: bool = False,
    max_steps: int = NLS_MAX_STEPS,
    throw: bool = False,
    blend_floor: float = 0.02,
    p_weight: float = 1.0,
    pd_eps: float = 0.0,
    init_floor: float = 1e-6,
    boundary_rtol: float = 1e-6,
    ftol: float = 1e-8,
    patience: int = 20,
) -> NLSResult:
    """Fit PSD hand and mechanism M, B, K to an FRF's Z_H and Z_T jointly.

    Arguments:
    - ``frf``: FRF with ``omega`` ``(N,)`` rad/s, ``Z_H``/``Z_T`` ``(N, n, n)`` N/m (and stds
      for ``"noise"``/``"blend"`` weights).
    - ``init``: starting model; default ``project_pd(wls(frf, omega_c, f_max_hz))`` (hand and
      mechanism = total − hand, each symmetrized with eigenvalues clipped at ``init_floor`` ×
      their largest).
    - ``weight``: ``"relative"`` | ``"paper"`` | ``"noise"`` | ``"blend"`` (module docstring).
    - ``f_max_hz``: fit band upper edge in Hz (default 40, see module docstring; ``None`` = all).
    - ``omega_c``: paper-weight corner, rad/s (used by ``"paper"`` and the WLS start).
    - ``solver``: the solver object (:mod:`hapid.fit._solvers`): an optimistix least-squares
      solver (run on the residual), an optimistix minimiser (run on ½‖r‖²) or
      :class:`~hapid.fit.JaxoptLM` (cross-check backend); its ``rtol``, ``atol`` are the
      Cauchy tolerances (on ``theta`` and on residuals, scaled units). Default
      :data:`~hapid.fit.DEFAULT_SOLVER`: ``optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10,
      linear_solver=lx.Normal(lx.Cholesky()))`` (the Cholesky normal equations:
      docs/conventions.md "CPU pitfalls"; ``lx.QR()`` is optimistix's default). By name:
      :func:`~hapid.fit.solver_from`.
    - ``use_P_residual``: add ``(P̂ − P)/‖P‖_F·p_weight`` residuals (needs invertible Z).
    - ``max_steps``: solver budget.
    - ``throw``: raise (also under ``jit``, via ``eqx.error_if``) if the fit did not converge.
    - ``blend_floor``: relative model-error floor of ``"blend"`` weights.
    - ``pd_eps``: add ``pd_eps·I`` (scaled units) to every matrix, making them strictly PD:
      then det Ẑ_H, det Ẑ_T have no closed-RHP root. The default 0 gives the bare ``L Lᵀ``,
      whose boundary can put a root at s = 0 or ∞ (hexapod6's rank-3 hand); ``PD_EPS``
      (1e-3, fit_ml's default) removes it there at ≤ 0.3 dB of P·P̂⁻¹ band, but a block
      that is truly zero (a single impedance loaded as Z_H = Z_T or Z_H = 0) then carries
      ``pd_eps·z_ref`` (2e-4 relative error in the noise-free single-impedance fit). The result's ``theta``
      (and its ``covariance``, by the delta method) is the Cholesky factor of the fitted
      matrices, floor included: ``theta_to_model(theta, scale)`` is ``model`` and
      ``nls_cost(theta, frf, scale=scale)`` is ``cost``; ``at_boundary`` flags the matrices
      whose ``L Lᵀ`` part (without the floor) is on the PSD boundary.
    - ``boundary_rtol``: an eigenvalue ≤ boundary_rtol × largest counts as on the boundary.
    - ``ftol``, ``patience``: least-squares solvers also stop (as converged) when the cost
      has not decreased by a relative ``ftol`` over ``patience`` consecutive steps
      (``hapid.fit._iterate``: the optimistix trust region otherwise never terminates on a
      cost flat to rounding). :class:`~hapid.fit.JaxoptLM` uses its own Madsen–Nielsen test
      instead (``rtol`` → xtol, ``atol`` → gtol).

    Returns an :class:`NLSResult`; check ``result.ok`` or call ``result.raise_if_failed()``:
    a fit that hit ``max_steps`` or failed is never reported as converged. Jittable and
    vmappable (``jax.vmap(lambda f: fit_nls(f, ...))(batch)``, or :func:`fit_nls_batch`).
    Raises ``ValueError`` for unknown options (a solver that is not one of the objects
    above, a string included) and (outside ``jit``) bad input: non-finite
    data, fewer than 3 frequencies in the band, missing/non-positive stds for noise weights,
    singular Z (P residual).
    """
    dyn, static = _options(
        weight=weight, f_max_hz=f_max_hz, omega_c=omega_c, solver=solver,
        use_P_residual=use_P_residual, max_steps=max_steps, throw=throw,
        blend_floor=blend_floor, p_weight=p_weight, pd_eps=pd_eps, init_floor=init_floor,
        boundary_rtol=boundary_rtol, ftol=ftol, patience=patience,
    )  # fmt: skip
    _check_data(frf, f_max_hz, weight, use_P_residual)
    _warn_jacobian_size(frf, use_P_residual)
    return _fit_core(frf, init, dyn, static)


def _options(
    *, weight, f_max_hz, omega_c, solver, use_P_residual, max_steps, throw,
    blend_floor, p_weight, pd_eps, init_floor, boundary_rtol, ftol, patience,
):  # fmt: skip
    """``(dyn, static)`` of :func:`fit_nls`'s options, every one given (the defaults live in
    :func:`fit_nls`'s signature only: :data:`_NLS_DEFAULTS`), checked. ``dyn["solver"]`` is
    the solver with array tolerances; ``static`` holds its label."""
    check_solver(solver)
    if not (isinstance(max_steps, int) and max_steps > 0):
        raise ValueError(f"max_steps must be a positive int, got {max_steps!r}")
    num = dict(
        f_max_hz=np.inf if f_max_hz is None else f_max_hz,
        omega_c=omega_c,
        max_steps=max_steps,
        ftol=ftol,
        patience=patience,
        blend_floor=blend_floor,
        p_weight=p_weight,
        pd_eps=pd_eps,
        init_floor=init_floor,
        boundary_rtol=boundary_rtol,
    )
    dyn = {
        k: jnp.asarray(v, dtype=jnp.int64 if k in ("max_steps", "patience") else jnp.float64)
        for k, v in num.items()
    }
    dyn["solver"] = with_array_tolerances(solver)
    static = (weight, solver_name(solver), bool(use_P_residual), bool(throw))
    static += (int(max_steps) if isinstance(solver, JaxoptLM) else None,)
    return dyn, static


@eqx.filter_jit
def _fit_core_batch(frfs, init, dyn, static):
    """:func:`_fit_core` for a batch (leading axis), default path only: ``lm`` with the
    Cholesky normal equations on the compressed residual (no P term). The set-up and the
    result are the single fit's, vmapped; the solver is :func:`hapid.fit._lm_batch.lm_compressed`
    (optimistix's LM step for step, without its per-step operator materialization) and the
    Laplace covariance :func:`~hapid.fit._lm_batch.covariance_batch` (structured inverse, ``eigh``
    only for fits whose information matrix is near singular); the ``pd_eps`` branch is taken
    once for the batch."""

    weight, solver_label, use_P, throw, _ = static
    d = dyn
    n = frfs.n

    def setup(frf, init):
        problem = make_problem(
            frf,
            weight=weight,
            f_max_hz=d["f_max_hz"],
            omega_c=d["omega_c"],
            blend_floor=d["blend_floor"],
            pd_eps=d["pd_eps"],
        )
        theta0 = _init_theta(frf, init, problem.scale, d["omega_c"], d["f_max_hz"], d["init_floor"])
        return problem.scale, problem.n_residuals, compress(problem), theta0

    scale, m, work, theta0 = jax.vmap(setup)(frfs, init)
    steps = (d["solver"].rtol, d["solver"].atol, d["max_steps"], d["ftol"], d["patience"])
    free, n_steps, code = jax.vmap(lambda w, t: lm_compressed(w, t, *steps))(work, theta0)
    inv, cost = covariance_batch(work, free)
    p = free.shape[-1]
    sigma2 = jnp.ones_like(cost) if weight == "noise" else 2.0 * cost / jnp.maximum(m - p, 1)
    cov = sigma2[:, None, None] * inv

    def absorb(t, c):
        G = jax.jacfwd(absorb_eps)(t, n, d["pd_eps"])
        return absorb_eps(t, n, d["pd_eps"]), G @ c @ G.T

    theta, cov = jax.lax.cond(
        d["pd_eps"] > 0, lambda: jax.vmap(absorb)(free, cov), lambda: (free, cov)
    )
    code = jax.vmap(final_status)(theta, cost, code)
    if throw:
        theta = eqx.error_if(
            theta,
            jnp.any(code != CONVERGED),
            "fit_nls_batch: a fit did not converge (status max_steps or failed)",
        )
    model = jax.vmap(theta_to_model)(theta, scale)
    at_boundary = jax.vmap(
        lambda t, s: boundary_report(theta_to_model(t, s), rtol=d["boundary_rtol"])
    )(free, scale)
    return NLSResult(
        model=model,
        theta=theta,
        scale=scale,
        status_code=code,
        n_steps=jnp.asarray(n_steps).astype(jnp.int32),
        cost=cost,
        covariance=cov,
        sigma2=sigma2,
        n_residuals=m,
        at_boundary=at_boundary,
        weight=weight,
        solver=solver_label,
    )


_NLS_DEFAULTS = {
    k: p.default
    for k, p in inspect.signature(fit_nls).parameters.items()
    if p.kind is inspect.Parameter.KEYWORD_ONLY
}
""":func:`fit_nls`'s keyword options and their defaults (read from its signature)."""


def fit_nls_batch(frfs: FRF, init: ImpedanceModel | None = None, **options) -> NLSResult:
    """:func:`fit_nls` over a batch of FRFs (leading axis of every array), one compile.

    ``init`` (optional) is a batched :class:`ImpedanceModel` (or batched
    :class:`NLSResult`). Returns a batched :class:`NLSResult` (``status`` an array of names,
    ``ok`` a bool array). Each fit equals ``fit_nls`` of that FRF alone (same steps and
    status, cost to rounding; ``tests/test_fit_batch.py``).

    The default path (the default solver, Levenberg–Marquardt on the Cholesky normal
    equations, with any tolerances; no P residual) runs as one batched program
    (:mod:`hapid.fit._lm_batch`); other options vmap :func:`fit_nls`.
    """
    unknown = set(options) - set(_NLS_DEFAULTS)
    if unknown:
        raise TypeError(f"fit_nls_batch: unknown option(s) {sorted(unknown)}")
    opts = _NLS_DEFAULTS | options
    fast = (
        is_default_lm(opts["solver"])
        and not opts["use_P_residual"]
        and isinstance(frfs, FRF)
        and np.ndim(frfs.omega) == 2
    )
    if not fast:
        if init is None:
            return eqx.filter_vmap(lambda f: fit_nls(f, **options))(frfs)
        return eqx.filter_vmap(lambda f, i: fit_nls(f, i, **options))(frfs, init)
    dyn, static = _options(**opts)
    _check_data(frfs, opts["f_max_hz"], static[0], False)
    _warn_jacobian_size(frfs, False)
    if init is not None:
        if isinstance(init, NLSResult):
            init = init.model
        if not isinstance(init, ImpedanceModel):
            raise ValueError(
                "fit_nls_batch: init must be None, an ImpedanceModel or an NLSResult, "
                f"got {type(init).__name__}"
            )
    return _fit_core_batch(frfs, init, dyn, static)


def nls_cost(theta: Float[Array, " p"], frf: FRF, scale: Scale | None = None, **options) -> Array:
    """``½‖r(θ)‖²`` of :func:`fit_nls`'s residual for ``frf`` (``options`` as ``make_problem``).

    Differentiable: ``jax.grad(nls_cost)(theta, frf, scale=result.scale)``.
    """
    return make_problem(frf, scale=scale, **options).cost(theta)
