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
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Complex, Float

from .._linalg import pinv_psd
from ..defaults import FIT_BAND_HZ
from ..frf import FRF
from ..impedance import ImpedanceModel, plant
from ._checks import band_mask, check_fit_input
from ._compress import compress
from ._iterate import iterate
from ._jaxopt_adapter import jaxopt_lm
from ._lm_batch import covariance_batch, lm_compressed
from ._pd import (
    Scale,
    boundary_report,
    model_to_theta,
    n_params,
    project_pd,
    scaled_pair,
    theta_to_model,
    theta_to_scaled,
)
from ._result import CONVERGED, FAILED, NLSResult
from ._wls import OMEGA_C_PAPER, wls

WEIGHTS = ("relative", "paper", "noise", "blend")
LEAST_SQUARES_SOLVERS = ("lm", "dogleg", "gauss_newton")
MINIMISERS = ("bfgs", "nonlinear_cg")
SOLVERS = LEAST_SQUARES_SOLVERS + MINIMISERS + ("jaxopt_lm",)
LINEAR_SOLVERS = ("cholesky", "qr")
#: relative weights: a block's norm is floored at this fraction of the other block's
RELATIVE_FLOOR = 1e-6
#: default ``pd_eps`` of fit_ml, opt-in for fit_nls (scaled units, relative to the data scale):
#: every matrix is ``L Lᵀ + PD_EPS·I``, strictly PD, so a matrix the fit drives to the PSD
#: boundary (hexapod6's rank-3 hand in rod space) cannot put a root of det Ẑ at s = 0 or ∞
PD_EPS = 1e-3


def data_scale(frf: FRF, f_max_hz: float | None = None) -> Scale:
    """The :class:`Scale` of an FRF's fit band: ω_ref = geometric-mean frequency (rad/s),
    z_ref = median |element| of Z_H and Z_T (N/m). Jittable."""
    mask = band_mask(frf.omega, f_max_hz)
    omega_ref = jnp.exp(jnp.sum(mask * jnp.log(frf.omega)) / jnp.sum(mask))
    mags = jnp.abs(jnp.stack([frf.Z_H, frf.Z_T], axis=1))  # (N, 2, n, n)
    valid = jnp.broadcast_to(mask[:, None, None, None] > 0, mags.shape)
    return Scale(omega_ref, median_nonneg(mags.ravel(), valid.ravel()))


def median_nonneg(x: Float[Array, " M"], valid) -> Float[Array, ""]:
    """``jnp.nanmedian`` of the entries of ``x`` (≥ 0, finite) where ``valid``, same value,
    without a sort (XLA's CPU sort took ~170 µs per fit of 1400 entries, the largest part of a
    fit's set-up): the lower middle order statistic is found exactly by bisection on the IEEE
    bit pattern (non-negative doubles order as their int64 bits), 63 fused count passes; the
    upper one is it or the next larger entry (one more pass)."""
    bits = jax.lax.bitcast_convert_type(jnp.where(valid, x, jnp.inf), jnp.int64)
    cnt = jnp.sum(valid)
    q = 0.5 * (cnt - 1).astype(x.dtype)  # jnp.quantile(..., 0.5, method="linear")
    lo_i, hi_i = jnp.floor(q), jnp.ceil(q)
    hw = q - lo_i
    k = lo_i.astype(jnp.int64)  # 0-based rank of the lower middle entry

    def step(_, lh):
        lo, hi = lh
        mid = lo + (hi - lo) // 2
        take = jnp.sum(bits <= mid) >= k + 1
        return jnp.where(take, lo, mid + 1), jnp.where(take, mid, hi)

    top = jnp.asarray(np.float64(np.inf).view(np.int64))
    _, low = jax.lax.fori_loop(0, 63, step, (jnp.zeros((), jnp.int64), top))
    # rank hi_i: the same entry if it repeats that far, else the smallest entry above it
    same = jnp.sum(bits <= low) >= hi_i.astype(jnp.int64) + 1
    high = jnp.where(same, low, jnp.min(jnp.where(bits > low, bits, top)))
    v_lo = jax.lax.bitcast_convert_type(low, x.dtype)
    v_hi = jax.lax.bitcast_convert_type(high, x.dtype)
    return v_lo * (1.0 - hw) + v_hi * hw


class Problem(eqx.Module):
    """The weighted residual ``r(θ)`` of one FRF (a callable pytree, ``r`` is ``(m,)`` real).

    All impedances are stored divided by ``scale.z_ref``; weights are ``(N, n, n)`` (complex
    for the paper weight) and already contain the band mask.
    """

    s: Complex[Array, " N"]  # jω/ω_ref
    Z_H: Complex[Array, "N n n"]  # scaled data
    Z_T: Complex[Array, "N n n"]
    W_H: Array
    W_T: Array
    P: Complex[Array, "N n n"] | None
    W_P: Array | None
    scale: Scale
    n_in_band: Array
    eps: Array  # pd_eps, scaled units

    @property
    def n(self) -> int:
        return int(self.Z_H.shape[-1])

    def model_arrays(self, theta):
        return scaled_pair(theta_to_scaled(theta, self.n, self.eps), self.s)

    def __call__(self, theta: Float[Array, " p"], args=None) -> Float[Array, " m"]:
        ZH, ZT = self.model_arrays(theta)
        errs = [self.W_H * (ZH - self.Z_H), self.W_T * (ZT - self.Z_T)]
        if self.P is not None:
            errs.append(self.W_P * (plant(ZH, ZT) - self.P))
        e = jnp.stack(errs)
        return jnp.concatenate([jnp.real(e).ravel(), jnp.imag(e).ravel()])

    def cost(self, theta: Float[Array, " p"], args=None) -> Float[Array, ""]:
        """``½‖r(θ)‖²``."""
        r = self(theta)
        return 0.5 * jnp.sum(r**2)

    @property
    def n_residuals(self) -> Array:
        """Real residuals inside the fit band (masked rows are excluded)."""
        blocks = 2 if self.P is None else 3
        return 2 * blocks * self.n**2 * self.n_in_band


def _check_data(frf: FRF, f_max_hz, weight: str, use_P_residual: bool) -> None:
    """The checks ``make_problem`` and ``fit_nls`` share: the weight's name and the data it
    needs (values only when concrete — outside ``jit``)."""
    if weight not in WEIGHTS:
        raise ValueError(f"weight must be one of {WEIGHTS}, got {weight!r}")
    check_fit_input(
        frf,
        f_max_hz,
        need_std=weight in ("noise", "blend"),
        positive_std=weight == "noise",  # blend has a relative floor: a zero std is fine
        need_invertible_Z=use_P_residual,
        what="fit_nls",
    )


def make_problem(
    frf: FRF,
    *,
    weight: str = "relative",
    f_max_hz: float | None = FIT_BAND_HZ,
    omega_c: float = OMEGA_C_PAPER,
    use_P_residual: bool = False,
    blend_floor: float = 0.02,
    p_weight: float = 1.0,
    pd_eps: float = 0.0,
    scale: Scale | None = None,
) -> Problem:
    """Build the residual of :func:`fit_nls` for ``frf`` (same options). Jittable.

    ``scale`` defaults to :func:`data_scale` of the band. ``make_problem(frf)(theta)`` is the
    residual vector, ``.cost(theta)`` the cost ``½‖r‖²`` (differentiable in ``theta``).
    """
    _check_data(frf, f_max_hz, weight, use_P_residual)
    scale = data_scale(frf, f_max_hz) if scale is None else scale
    mask = band_mask(frf.omega, f_max_hz)[:, None, None]
    zr = scale.z_ref
    Z_H, Z_T = frf.Z_H / zr, frf.Z_T / zr
    fro = lambda Z: jnp.linalg.norm(Z, axis=(-2, -1))[:, None, None]  # noqa: E731
    if weight == "relative":
        # a block whose data is zero (a single impedance loaded with Z_H = 0) has no size of
        # its own: it is weighted relative to the other block (1e6/‖Z_other‖), not 1/0
        nH, nT = fro(Z_H), fro(Z_T)
        W_H = mask / jnp.maximum(nH, RELATIVE_FLOOR * nT)
        W_T = mask / jnp.maximum(nT, RELATIVE_FLOOR * nH)
    elif weight == "paper":
        h = (omega_c**2 / (1j * frf.omega + omega_c) ** 2)[:, None, None]
        W_H = W_T = mask * h
    elif weight == "noise":
        W_H, W_T = mask * np.sqrt(2.0) * zr / frf.Z_H_std, mask * np.sqrt(2.0) * zr / frf.Z_T_std
    else:  # blend

        def _blend(std, Z):
            return mask * zr / jnp.sqrt(std**2 / 2 + (blend_floor * zr * fro(Z)) ** 2)

        W_H, W_T = _blend(frf.Z_H_std, Z_H), _blend(frf.Z_T_std, Z_T)
    W_H = jnp.broadcast_to(W_H, Z_H.shape)
    W_T = jnp.broadcast_to(W_T, Z_T.shape)
    P = W_P = None
    if use_P_residual:
        P = plant(frf.Z_H, frf.Z_T)
        W_P = jnp.broadcast_to(p_weight * mask / fro(P), P.shape)
    return Problem(
        s=1j * frf.omega / scale.omega_ref,
        Z_H=Z_H,
        Z_T=Z_T,
        W_H=W_H,
        W_T=W_T,
        P=P,
        W_P=W_P,
        scale=scale,
        n_in_band=jnp.sum(mask).astype(jnp.int64),
        eps=jnp.asarray(pd_eps, dtype=float),
    )


def _linear_solver(name: str):
    if name == "cholesky":
        return lx.Normal(lx.Cholesky())
    return lx.QR()


def _run_solver(
    problem: Problem, theta0, solver, rtol, atol, max_steps, linear_solver, ftol, patience
):
    if solver == "jaxopt_lm":
        return jaxopt_lm(problem, theta0, max_steps=max_steps, rtol=rtol, atol=atol)
    if solver in LEAST_SQUARES_SOLVERS:
        cls = {
            "lm": optx.LevenbergMarquardt,
            "dogleg": optx.Dogleg,
            "gauss_newton": optx.GaussNewton,
        }[solver]
        opt = cls(rtol=rtol, atol=atol, linear_solver=_linear_solver(linear_solver))
        fn = lambda th, args: (problem(th), None)  # noqa: E731
        stall = True
    else:
        cls = {"bfgs": optx.BFGS, "nonlinear_cg": optx.NonlinearCG}[solver]
        opt = cls(rtol=rtol, atol=atol)
        fn = lambda th, args: (problem.cost(th), None)  # noqa: E731
        # line-search minimisers legitimately have long runs of rejected trials early on,
        # and their own Cauchy test on the scalar cost terminates: no stagnation rule
        stall = False
    return iterate(
        opt,
        fn,
        problem.cost,
        theta0,
        max_steps=max_steps,
        ftol=ftol,
        patience=patience,
        stall=stall,
    )


def laplace_covariance(
    problem: Problem, theta: Float[Array, " p"], noise_weights: bool, n_residuals=None
):
    """``(σ̂²(JᵀJ)⁺, σ̂², cost)`` at ``theta``; σ̂² = 1 for noise weights else 2·cost/(m−p).

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
    return sigma2 * pinv_psd(J.T @ J), sigma2, cost


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
    """The jitted fit. ``dyn`` holds numeric options as arrays (one compile serves a sweep
    over them); ``static`` the structural ones (weight, solver, ...)."""
    weight, solver, use_P, linear_solver, throw, jaxopt_steps = static
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
    theta, n_steps, code = _run_solver(
        work,
        theta0,
        solver,
        d["rtol"],
        d["atol"],
        max_steps,
        linear_solver,
        d["ftol"],
        d["patience"],
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
        solver=solver,
    )


#: fit_nls warns when its largest array (the dense P-residual Jacobian, or the compressed
#: residual's QR factors without the P term) exceeds this.
JACOBIAN_WARN_BYTES = 1e9


def _warn_jacobian_size(frf: FRF, use_P_residual: bool) -> None:
    """Warn before a fit whose largest array would take more than a gigabyte.

    With the P residual the solver and the Laplace covariance materialize the dense
    ``m × p`` Jacobian, ``m = 12·n²·N`` rows (the fit band is a 0/1 mask, so out-of-band
    frequencies still occupy rows: ``frf.band(...)`` shrinks the problem, ``f_max_hz`` does
    not). Without it the residual is compressed (``hapid.fit._compress``) and the largest
    arrays are the thin QR's ``8N × 6`` blocks of the ``n(n+1)/2`` symmetric elements.
    """
    shape = np.shape(frf.Z_H)
    N, n = shape[-3], shape[-1]
    batch = int(np.prod(shape[:-3], dtype=np.int64))
    if use_P_residual:
        m = 2 * 3 * n * n * N
        nbytes = 8.0 * m * n_params(n) * batch
        what = f"a dense {m} × {n_params(n)} Jacobian"
    else:
        nbytes = 3 * 8.0 * 8 * N * 6 * (n * (n + 1) // 2) * batch  # M, Q and a copy
        what = "the compressed residual's QR factors"
    if nbytes > JACOBIAN_WARN_BYTES:
        warnings.warn(
            f"fit_nls: n = {n} rods × {N} frequencies gives {what} of {nbytes / 1e9:.1f} GB; "
            "drop frequencies with frf.band(...) or decimate the grid — f_max_hz only masks rows",
            UserWarning,
            stacklevel=3,
        )


def fit_nls(
    frf: FRF,
    init: ImpedanceModel | NLSResult | None = None,
    *,
    weight: str = "relative",
    f_max_hz: float | None = FIT_BAND_HZ,
    omega_c: float = OMEGA_C_PAPER,
    solver: str = "lm",
    use_P_residual: bool = False,
    max_steps: int = 500,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    throw: bool = False,
    blend_floor: float = 0.02,
    p_weight: float = 1.0,
    pd_eps: float = 0.0,
    init_floor: float = 1e-6,
    linear_solver: str = "cholesky",
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
    - ``solver``: optimistix ``"lm"`` (Levenberg–Marquardt, default), ``"dogleg"``,
      ``"gauss_newton"``; optimistix minimisers of ½‖r‖² ``"bfgs"``, ``"nonlinear_cg"``; or
      ``"jaxopt_lm"`` (cross-check backend).
    - ``use_P_residual``: add ``(P̂ − P)/‖P‖_F·p_weight`` residuals (needs invertible Z).
    - ``max_steps``, ``rtol``, ``atol``: solver budget and Cauchy tolerances (on ``theta`` and
      on residuals, in scaled units).
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
    - ``linear_solver``: ``"cholesky"`` (normal equations, default; docs/conventions.md "CPU pitfalls")
      or ``"qr"`` (optimistix's default) for the Gauss–Newton-type solvers.
    - ``boundary_rtol``: an eigenvalue ≤ boundary_rtol × largest counts as on the boundary.
    - ``ftol``, ``patience``: (``lm``, ``dogleg``, ``gauss_newton``) also stop (as converged)
      when the cost has not decreased by a
      relative ``ftol`` over ``patience`` consecutive steps (``hapid.fit._iterate``: the
      optimistix trust region otherwise never terminates on a cost flat to rounding).
      ``jaxopt_lm`` uses its own Madsen–Nielsen test instead (``rtol`` → xtol, ``atol`` → gtol).

    Returns an :class:`NLSResult`; check ``result.ok`` or call ``result.raise_if_failed()``:
    a fit that hit ``max_steps`` or failed is never reported as converged. Jittable and
    vmappable (``jax.vmap(lambda f: fit_nls(f, ...))(batch)``, or :func:`fit_nls_batch`).
    Raises ``ValueError`` for unknown options and (outside ``jit``) bad input: non-finite
    data, fewer than 3 frequencies in the band, missing/non-positive stds for noise weights,
    singular Z (P residual).
    """
    dyn, static = _options(
        weight=weight, f_max_hz=f_max_hz, omega_c=omega_c, solver=solver,
        use_P_residual=use_P_residual, max_steps=max_steps, rtol=rtol, atol=atol, throw=throw,
        blend_floor=blend_floor, p_weight=p_weight, pd_eps=pd_eps, init_floor=init_floor,
        linear_solver=linear_solver, boundary_rtol=boundary_rtol, ftol=ftol, patience=patience,
    )  # fmt: skip
    _check_data(frf, f_max_hz, weight, use_P_residual)
    _warn_jacobian_size(frf, use_P_residual)
    return _fit_core(frf, init, dyn, static)


def _options(
    *, weight, f_max_hz, omega_c, solver, use_P_residual, max_steps, rtol, atol, throw,
    blend_floor, p_weight, pd_eps, init_floor, linear_solver, boundary_rtol, ftol, patience,
):  # fmt: skip
    """``(dyn, static)`` of :func:`fit_nls`'s options, every one given (the defaults live in
    :func:`fit_nls`'s signature only: :data:`_NLS_DEFAULTS`), checked."""
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    if linear_solver not in LINEAR_SOLVERS:
        raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS}, got {linear_solver!r}")
    if not (isinstance(max_steps, int) and max_steps > 0):
        raise ValueError(f"max_steps must be a positive int, got {max_steps!r}")
    num = dict(
        f_max_hz=np.inf if f_max_hz is None else f_max_hz,
        omega_c=omega_c,
        max_steps=max_steps,
        rtol=rtol,
        atol=atol,
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
    static = (weight, solver, bool(use_P_residual), linear_solver, bool(throw))
    static += (int(max_steps) if solver == "jaxopt_lm" else None,)
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

    weight, solver, use_P, linear_solver, throw, _ = static
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
    steps = (d["rtol"], d["atol"], d["max_steps"], d["ftol"], d["patience"])
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
        solver=solver,
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

    The default path (``solver="lm"``, ``linear_solver="cholesky"``, no P residual) runs as
    one batched program (:mod:`hapid.fit._lm_batch`); other options vmap :func:`fit_nls`.
    """
    unknown = set(options) - set(_NLS_DEFAULTS)
    if unknown:
        raise TypeError(f"fit_nls_batch: unknown option(s) {sorted(unknown)}")
    opts = _NLS_DEFAULTS | options
    fast = (
        opts["solver"] == "lm"
        and opts["linear_solver"] == "cholesky"
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


__all__ = ["fit_nls", "fit_nls_batch", "make_problem", "nls_cost", "data_scale", "n_params"]
