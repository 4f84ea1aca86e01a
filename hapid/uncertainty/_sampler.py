# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""emcee driver, Laplace approximations and the :class:`PosteriorSamples` value object.

- :func:`laplace_samples` — the fast path: Gaussian draws ``N(θ̂, Σ_NLS)`` from an
  :class:`~hapid.fit.NLSResult` (θ only, no model-error parameters).
- :func:`laplace_posterior` — MAP of a :class:`LogPosterior` (BFGS from the NLS optimum)
  and the inverse Hessian there: the Gaussian that :func:`sample_posterior` draws its
  walkers from (full draws need no burn-in, docs/conventions.md "emcee in ~90 dimensions").
- :func:`sample_posterior` — ``emcee.EnsembleSampler`` with ``vectorize=True`` on the
  jitted, vmapped log-posterior; optional HDF5 backend, tqdm progress bar, autocorrelation
  time, effective sample size, and a :class:`ShortChainWarning` below 50 τ.

Move default: ``DEMove()``. Measured with ``benchmarks/bench_uncertainty.py`` (see its
header): DE beats the stretch move by a wide margin in ESS per second at d ≈ 20–92 (and
docs/conventions.md measured ≈ 8× at d = 90). ``DESnookerMove`` (wrong target in emcee 3.1.6) and
``KDEMove`` (fails at this dimension) are not offered.
"""

from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from pathlib import Path

import emcee
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..fit._pd import MATRIX_NAMES, Scale, n_from_params, n_params, theta_to_model
from ..fit._result import NLSResult
from ..impedance import ImpedanceModel
from ._likelihood import (
    LogPosterior,
    batched_log_prob,
    fold_theta,
    param_names,
)
from ._mode import (
    _canonical_with_cov,
    _map_hessian,
    check_initial_state,
    initial_point,
)

MOVES = ("de", "stretch", "de_mix", "laplace_de")
TAU_MULTIPLE = 50.0


class ShortChainWarning(UserWarning):
    """The chain is shorter than 50 integrated autocorrelation times: estimates unreliable."""


class LaplaceIndependenceMove(emcee.moves.MHMove):
    """Independence Metropolis–Hastings: every walker proposes a fresh draw from a
    multivariate Student-t (``dof``) centred on the Laplace mean with the Laplace covariance
    inflated by ``inflate²``, accepted with ``p(x′) q(x) / (p(x) q(x′))``.

    Valid for any target (the ``q`` ratio is exact); efficient when the posterior is close to
    its Laplace approximation — then the autocorrelation time is a few steps whatever the
    dimension, where ensemble moves (stretch, DE) need ``O(d)`` steps or more. The t tails
    (heavier than the Gaussian) keep the importance ratio bounded when the posterior's tails
    are heavier than Laplace's. Mixed with ``DEMove`` (``moves="laplace_de"``) so the parts of
    the posterior the Gaussian misses (a Cholesky diagonal near the PSD boundary, skew) are
    still explored by local moves.
    """

    def __init__(self, mean, cov, dof: float = 30.0, inflate: float = 1.0):
        mean = np.asarray(mean, dtype=np.float64)
        cov = np.asarray(cov, dtype=np.float64) * inflate**2
        lam, V = np.linalg.eigh(0.5 * (cov + cov.T))
        if not (np.all(np.isfinite(lam)) and lam.min() > 0):
            raise ValueError(
                "LaplaceIndependenceMove: the covariance must be finite and positive definite"
            )
        root = V * np.sqrt(lam)
        whiten = V / np.sqrt(lam)  # x ↦ (x − mean) @ whiten gives standard coordinates
        d = mean.shape[0]

        def log_q(x):
            z = (x - mean) @ whiten
            return -0.5 * (dof + d) * np.log1p(np.sum(z * z, axis=1) / dof)

        def proposal(coords, random):
            K = coords.shape[0]
            z = random.randn(K, d)
            w = np.sqrt(dof / random.chisquare(dof, K))
            new = mean + (z * w[:, None]) @ root.T
            return new, log_q(coords) - log_q(new)

        super().__init__(proposal, ndim=d)


def _moves(name: str, laplace=None):
    if name == "laplace_de":
        if laplace is None:
            raise ValueError("moves='laplace_de' needs the Laplace Gaussian: pass init as an "
                             "NLSResult or a (mean, cov) pair")  # fmt: skip
        return [(LaplaceIndependenceMove(*laplace), 0.5), (emcee.moves.DEMove(), 0.5)]
    if name == "de":
        return [(emcee.moves.DEMove(), 1.0)]
    if name == "stretch":
        return [(emcee.moves.StretchMove(), 1.0)]
    if name == "de_mix":  # DE plus 10 % γ = 1 jumps (mode hopping between reflections)
        return [(emcee.moves.DEMove(), 0.9), (emcee.moves.DEMove(gamma0=1.0), 0.1)]
    raise ValueError(f"moves must be one of {MOVES}, got {name!r}")


@dataclasses.dataclass(frozen=True)
class PosteriorSamples:
    """Posterior draws of the PD-parameterized model.

    - ``samples``: ``(S, d)`` — folded θ (``d ≥ p = 6·n(n+1)/2``, diagonals ≥ 0, in ``scale``
      units) followed by any model-error coordinates (``log_tau_H``, ``log_tau_M``, and for
      the GP model error ``log_ell_H``, ``log_ell_M``, ``beta_H``, ``beta_M``).
    - ``predictive``: the fit data the model-error term is conditioned on
      (:meth:`LogPosterior.predictive_data`), or None (Laplace-NLS draws, old files).
    - ``measured``: the whole measured FRF the posterior was built from (``omega (K,)``
      rad/s, ``Z_H``, ``Z_T (K, n, n)``: every measured frequency, also above the fit band),
      or None. The robust check and the tuner draw the loop from it
      (:func:`hapid.uncertainty.loop_gp_check`).
    - ``log_prob``: ``(S,)`` log-posterior of each draw (NaN for Laplace draws).
    - ``scale``: the :class:`~hapid.fit.Scale` θ is expressed in.
    - ``n``: rods. ``names``: the ``d`` coordinate names.
    - ``diagnostics``: method, acceptance fraction, τ per parameter, ESS, steps, timings …
    """

    samples: np.ndarray
    log_prob: np.ndarray
    scale: Scale
    n: int
    names: tuple[str, ...]
    diagnostics: dict = dataclasses.field(default_factory=dict)
    predictive: dict | None = None  # LogPosterior.predictive_data(): fit data for predictions
    measured: dict | None = None  # the whole measured FRF: omega, Z_H, Z_T

    def __post_init__(self):
        s = np.asarray(self.samples)
        p = n_params(self.n)
        if s.ndim != 2 or s.shape[1] not in (p, p + 2, p + 6, p + 8, p + 10):
            raise ValueError(
                f"PosteriorSamples: samples must be (S, {p}) or (S, {p}+model-error) for n = "
                f"{self.n}, got shape {s.shape}"
            )
        if np.shape(self.log_prob) != (s.shape[0],):
            raise ValueError("PosteriorSamples: log_prob must be (S,)")
        if len(self.names) != s.shape[1]:
            raise ValueError("PosteriorSamples: names must match the number of columns")

    @property
    def n_samples(self) -> int:
        return int(self.samples.shape[0])

    @property
    def n_theta(self) -> int:
        return n_params(self.n)

    @property
    def theta(self) -> np.ndarray:
        """``(S, p)`` folded θ (canonical factors, non-negative diagonals)."""
        return self.samples[:, : self.n_theta]

    @property
    def tau(self) -> np.ndarray | None:
        """``(S, 2)`` relative model-error scales τ_H, τ_M (None without model error)."""
        extra = self.samples[:, self.n_theta : self.n_theta + 2]
        return np.exp(extra) if extra.shape[1] else None

    @property
    def ell(self) -> np.ndarray | None:
        """``(S, 2)`` GP length scales ℓ_H, ℓ_M (log-frequency units; None unless gp)."""
        extra = self.samples[:, self.n_theta + 2 : self.n_theta + 4]
        return np.exp(extra) if extra.shape[1] else None

    @property
    def error_kind(self) -> str:
        """``"none"``, ``"white"``, ``"gp"`` or ``"gp_corr"`` (from the number of model-error
        columns: 0, 2, 6 or 8, 10)."""
        k = self.samples.shape[1] - self.n_theta
        return {0: "none", 2: "white", 6: "gp", 8: "gp", 10: "gp_corr"}[k]

    def models(self, idx=None) -> ImpedanceModel:
        """Batched :class:`ImpedanceModel` (arrays ``(S, n, n)``; physical units)."""
        th = jnp.asarray(self.theta if idx is None else self.theta[idx])
        return _models(th, self.scale)

    def physical(self) -> dict[str, np.ndarray]:
        """``{"M_H": (S, n, n), …, "K_M": …}`` physical matrices of every draw."""
        m = self.models()
        h, mech = m.hand, m.mechanism
        vals = (h.M, h.B, h.K, mech.M, mech.B, mech.K)
        return {
            k: np.asarray(v)
            for k, v in zip(("M_H", "B_H", "K_H", "M_M", "B_M", "K_M"), vals, strict=True)
        }

    @property
    def ok(self) -> bool:
        """Every draw finite, and the sampler's own convergence check passed where it made one
        (emcee: chain ≥ 50 τ; Laplace: the mode search converged)."""
        d = self.diagnostics
        lap = d.get("laplace") if isinstance(d.get("laplace"), dict) else {}
        conv = d.get("converged_50tau", lap.get("converged", d.get("converged", True)))
        return bool(np.all(np.isfinite(np.asarray(self.samples)))) and bool(conv)

    @property
    def status(self) -> str:
        """``"converged"`` or ``"not converged"`` (see :attr:`ok`)."""
        return "converged" if self.ok else "not converged"

    def summary(self) -> str:
        d = self.diagnostics
        parts = [f"{d.get('method', '?')}: {self.n_samples} samples, d = {self.samples.shape[1]}"]
        for k in ("acceptance_fraction", "tau_max", "steps_over_tau", "ess_min", "ess_per_s"):
            if k in d and d[k] is not None:
                parts.append(f"{k} {d[k]:.4g}")
        return "; ".join(parts)


@eqx.filter_jit
def _models(theta, scale):
    return jax.vmap(lambda t: theta_to_model(t, scale))(theta)


# --- Laplace ---------------------------------------------------------------------------


def _check_key(key):
    if isinstance(key, int):
        return jax.random.PRNGKey(key)
    return key


def _held_boundary(cov, n: int, boundary) -> np.ndarray:
    """``cov`` conditioned on the factor entries of the matrices in ``boundary`` (names of
    :data:`~hapid.fit._pd.MATRIX_NAMES`) staying at the fit's values: the Schur complement
    ``Σ_oo − Σ_of Σ_ff⁺ Σ_fo`` on the other entries, zero rows and columns for the held ones.

    Why: at the PSD boundary a matrix's Cholesky factor is ≈ 0, where the model does not
    depend on it to first order, so ``σ̂²(JᵀJ)⁺`` gives it a standard deviation of ~10⁴ (in
    scaled units; cu5's ``K_M`` on the paper protocol) and a draw's matrix ``LLᵀ`` lands 10⁵–
    10⁸ times the fit's size — every draw. ``hapid posterior`` holds these matrices
    (:func:`~hapid.uncertainty.boundary_fixed`); this is the same rule for the Laplace draws
    of a fit."""
    t = n * (n + 1) // 2  # factor entries per matrix, in MATRIX_NAMES order
    held = np.repeat([name in boundary for name in MATRIX_NAMES], t)
    if not held.any():
        return cov
    o, f = ~held, held
    S_of = cov[np.ix_(o, f)]
    cond = (
        cov[np.ix_(o, o)]
        - S_of @ np.linalg.pinv(cov[np.ix_(f, f)], rcond=1e-12, hermitian=True) @ S_of.T
    )
    out = np.zeros_like(cov)
    out[np.ix_(o, o)] = 0.5 * (cond + cond.T)
    return out


def laplace_samples(
    nls_result: NLSResult, n_samples: int, key=0, *, fix_boundary: bool = True
) -> PosteriorSamples:
    """Fast path: ``n_samples`` draws of θ from ``N(θ̂, Σ)`` of an NLS fit (no MCMC).

    ``Σ = nls_result.covariance`` (``σ̂²(JᵀJ)⁺``). The NLS θ̂ is first made canonical (column
    signs flipped so diagonals are ≥ 0, same model, same linear map on Σ); draws are then
    folded (``|diag|``). With noise weights this is the Laplace approximation of the
    pure-noise posterior under a flat prior; with relative/blend weights its σ̂² absorbs the
    model error as a single scale. ``key``: a JAX PRNG key or an int seed.

    ``fix_boundary`` (default, as ``hapid posterior``): the matrices the fit put on the PSD
    boundary (``nls_result.boundary``) are held at the fit's value and the other entries drawn
    from the Gaussian conditioned on that (:func:`_held_boundary`: without it every draw of
    cu5's paper fit has a device stiffness 10⁵–10⁸ times the fit's). ``False``: the plain
    ``N(θ̂, Σ)``.
    """
    if not isinstance(nls_result, NLSResult):
        raise ValueError(f"laplace_samples: expected an NLSResult, got {type(nls_result).__name__}")
    if np.ndim(nls_result.theta) != 1:
        raise ValueError("laplace_samples: an unbatched NLSResult is required")
    if not (isinstance(n_samples, int | np.integer) and n_samples > 0):
        raise ValueError(f"n_samples must be a positive int, got {n_samples!r}")
    theta, cov = _canonical_with_cov(
        np.asarray(nls_result.theta), np.asarray(nls_result.covariance)
    )
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(cov))):
        raise ValueError("laplace_samples: the NLS result has a non-finite θ or covariance")
    n = n_from_params(theta.shape[0])
    if fix_boundary and nls_result.boundary:
        cov = _held_boundary(cov, n, tuple(nls_result.boundary))
    draws = _mvn(_check_key(key), theta, cov, n_samples)
    return PosteriorSamples(
        samples=fold_theta(draws),
        log_prob=np.full(n_samples, np.nan),
        scale=nls_result.scale,
        n=n,
        names=tuple(param_names(n, model_error=False)),
        diagnostics={"method": "laplace_nls", "mean": theta, "cov": cov},
    )


def _mvn(key, mean, cov, k):
    """Draws from N(mean, cov) via a symmetric square root (PSD cov allowed)."""
    lam, V = np.linalg.eigh(0.5 * (cov + cov.T))
    root = V * np.sqrt(np.clip(lam, 0.0, None))
    z = np.asarray(jax.random.normal(key, (k, mean.shape[0])))
    return mean + z @ root.T


def laplace_posterior(
    post: LogPosterior, x0, *, max_steps: int = 3000, rtol: float = 1e-9, atol: float = 1e-9
) -> tuple[np.ndarray, np.ndarray, dict]:
    """MAP and Laplace covariance ``(x_map (d,), cov (d, d), info)`` of a :class:`LogPosterior`.

    BFGS (optimistix) on ``−log p`` from ``x0`` (e.g. the NLS θ followed by the prior mean
    of log τ). The covariance is the inverse Hessian with its eigenvalues floored at the
    prior precision ``1/prior_scale²`` (the prior alone contributes that much curvature; a
    negative curvature at a kink ``|θ_jj| = 0`` would otherwise give nonsense). ``info``:
    ``steps``, ``converged``, ``log_prob`` at the MAP.
    """
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    if x0.shape != (post.dim,):
        raise ValueError(f"laplace_posterior: x0 must be ({post.dim},), got {x0.shape}")
    if not bool(jnp.all(jnp.isfinite(x0))):
        raise ValueError("laplace_posterior: x0 contains NaN or inf")
    if not np.isfinite(float(post(x0))):
        raise ValueError("laplace_posterior: the log-posterior at x0 is not finite")
    post_u = post.unconstrained()  # matrix coordinates: the Gaussian before the PSD cone
    xm, steps, ok, H = _map_hessian(post_u, x0, max_steps, rtol, atol)
    xm, H = np.asarray(xm), np.asarray(H)
    lam, V = np.linalg.eigh(0.5 * (H + H.T))
    floor = 1.0 / post.prior_scale**2
    lam = np.maximum(lam, floor)
    cov = (V / lam) @ V.T
    if post.parameterization == "cholesky" and not post.free_idx:
        xm = np.concatenate([fold_theta(xm[: post.n_theta]), xm[post.n_theta :]])
    info = {"steps": int(steps), "converged": bool(ok), "log_prob": float(post_u(jnp.asarray(xm))),
            "mode_in_cone": bool(np.isfinite(float(post(jnp.asarray(xm)))))}  # fmt: skip
    return xm, cov, info


def posterior_laplace_samples(post: LogPosterior, n_samples: int, init, key=0) -> PosteriorSamples:
    """Fast path from a :class:`LogPosterior`: its Laplace Gaussian (:func:`laplace_posterior`
    from ``init``, an :class:`NLSResult` or a start ``x0``), ``n_samples`` draws, each moved
    into the PSD cone (:meth:`LogPosterior.project`; matrix parameterization) and returned as
    canonical Cholesky θ with the model-error coordinates.

    In matrix coordinates this is the Gaussian of the untruncated linear-Gaussian posterior
    (exact for fixed τ) *projected* onto the cone — not the truncated posterior emcee samples:
    draws of a matrix at the PSD boundary pile up on the boundary instead of being reweighted.
    Fine for margins and bands; use :func:`sample_posterior` for calibrated intervals.
    """
    if not (isinstance(n_samples, int | np.integer) and n_samples > 0):
        raise ValueError(f"n_samples must be a positive int, got {n_samples!r}")
    x0 = (
        initial_point(post, init)
        if isinstance(init, NLSResult)
        else np.asarray(init, dtype=np.float64)
    )
    mean, cov, info = laplace_posterior(post, x0)
    draws = post.project(_mvn(_check_key(key), mean, cov, n_samples))
    theta, extra = post.split(draws)
    return PosteriorSamples(
        samples=np.concatenate([theta, extra], axis=1),
        log_prob=np.asarray(post.log_prob_numpy(draws)),
        scale=post.scale,
        n=post.n,
        names=tuple(param_names(post.n, post.kind if post.model_error else "none")),
        diagnostics={"method": f"laplace_{post.parameterization}", "laplace": info},
        predictive=post.predictive_data(),
    )


# --- emcee -----------------------------------------------------------------------------


def _autocorr(sampler, discard):
    """``get_autocorr_time(quiet=True)`` without emcee's log message (we warn ourselves)."""
    logging.disable(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return np.asarray(sampler.get_autocorr_time(discard=discard, quiet=True))
    finally:
        logging.disable(logging.NOTSET)


def _diagnostics(sampler, discard, thin_by, n_walkers, wall_s, method_name, tau_multiple):
    chain_len = sampler.iteration  # stored steps
    acc = sampler.acceptance_fraction
    tau_stored = _autocorr(sampler, discard)
    tau = np.asarray(tau_stored) * thin_by  # in sampler steps
    steps = (chain_len - discard) * thin_by
    tau_max = float(np.nanmax(tau))
    ess = n_walkers * steps / tau
    out = {
        "method": f"emcee ({method_name})",
        "n_walkers": int(n_walkers),
        "n_steps": int(chain_len * thin_by),
        "discard_steps": int(discard * thin_by),
        "thin_by": int(thin_by),
        "acceptance_fraction": float(np.mean(acc)),
        "acceptance_min": float(np.min(acc)),
        "tau": tau,
        "tau_max": tau_max,
        "steps_over_tau": float(steps / tau_max),
        "ess": ess,
        "ess_min": float(np.nanmin(ess)),
        "wall_s": float(wall_s),
        "ess_per_s": float(np.nanmin(ess) / wall_s) if wall_s > 0 else None,
        "converged_50tau": bool(steps >= tau_multiple * tau_max),
    }
    return out


def _adaptive_bar(progress, max_steps: int):
    """One tqdm bar for an adaptive (chunked) run: total = ``max_steps``, the run's upper bound
    (it usually stops earlier, at 50 τ); ``None`` without ``progress``."""
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=int(max_steps), desc="emcee (to 50 τ)", unit="step")


def _run_chunk(sampler, state, n: int, thin_by: int, bar):
    """``sampler.run_mcmc(state, n, thin_by)`` advancing ``bar`` (steps) instead of emcee's
    own per-call bar."""
    if bar is None:
        return sampler.run_mcmc(state, n, thin_by=thin_by, progress=False)
    last = state
    for last in sampler.sample(state, iterations=n, thin_by=thin_by):  # noqa: B007
        bar.update(thin_by)
    return last


def sample_posterior(
    post: LogPosterior,
    init,
    *,
    n_steps: int | None = None,
    n_walkers: int | None = None,
    moves: str = "de",
    seed: int = 0,
    progress: bool = False,
    backend_path: str | Path | None = None,
    discard: float = 0.1,
    max_steps: int = 40000,
    check_every: int = 2000,
    max_stored: int = 2000,
    tau_multiple: float = TAU_MULTIPLE,
) -> PosteriorSamples:
    """Sample ``post`` with ``emcee.EnsembleSampler(vectorize=True)``.

    ``init`` is one of: an ``(W, d)`` array of walkers; a ``(mean, cov)`` pair (walkers are
    full Gaussian draws); an :class:`~hapid.fit.NLSResult` (→ :func:`laplace_posterior`
    around its θ, then Gaussian draws).

    - ``n_steps``: sampler steps. ``None`` (default): run in chunks of ``check_every`` until
      the chain is ``≥ tau_multiple`` (50) integrated autocorrelation times long and τ has
      settled (changed < 5 %), or ``max_steps``.
    - ``n_walkers``: default ``2·d + 2`` (fewer than ``2·d`` is a ``ValueError``).
    - ``moves``: ``"de"`` (default, ``DEMove()``), ``"de_mix"``, ``"stretch"``.
    - ``progress``: tqdm bar (emcee's ``progress=``). ``backend_path``: an HDF5 file
      (``emcee.backends.HDFBackend``, needs h5py; reset at the start of the run).
    - ``discard``: fraction of the chain dropped at the start (default 10 %; walkers drawn
      from the Laplace Gaussian need little or none).
    - ``max_stored``: the chain is thinned (``thin_by``) so at most about this many steps
      are stored (memory: steps × walkers × d × 8 bytes).

    The returned draws are the kept chain thinned to about two per autocorrelation time
    (``diagnostics["thin_output"]`` steps apart). Returns :class:`PosteriorSamples` with
    diagnostics (acceptance fraction, τ per
    parameter in steps, ESS = walkers × steps / τ, wall time, ESS/s). Warns
    :class:`ShortChainWarning` when the kept chain is shorter than 50 τ_max.
    """
    d = post.dim
    rng = np.random.default_rng(seed)
    W = 2 * d + 2 if n_walkers is None else int(n_walkers)
    if W < 2 * d:
        raise ValueError(
            f"n_walkers = {W} for d = {d} parameters: emcee's ensemble moves need at least "
            f"2·d = {2 * d} walkers"
        )
    if not (0.0 <= discard < 1.0):
        raise ValueError(f"discard must be a fraction in [0, 1), got {discard}")
    if moves not in MOVES:
        raise ValueError(f"moves must be one of {MOVES}, got {moves!r}")
    lp_fn = batched_log_prob(post)
    laplace_info = None
    if isinstance(init, NLSResult):
        mean, cov, laplace_info = laplace_posterior(post, initial_point(post, init))
        init = (mean, cov)
    if isinstance(init, tuple):
        mean, cov = (np.asarray(a, dtype=np.float64) for a in init)
        if mean.shape != (d,) or cov.shape != (d, d):
            raise ValueError(
                f"init (mean, cov) must be ({d},) and ({d}, {d}), got {mean.shape}, {cov.shape}"
            )
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError("init: the Gaussian's mean or covariance contains NaN or inf")
        x0 = post.project(_mvn(jax.random.PRNGKey(int(rng.integers(2**31))), mean, cov, W))
        lp = lp_fn(x0)
        for _ in range(20):  # redraw the rare walker in a region of zero density
            bad = ~np.isfinite(lp)
            if not bad.any():
                break
            x0[bad] = post.project(
                _mvn(jax.random.PRNGKey(int(rng.integers(2**31))), mean, cov, int(bad.sum()))
            )
            lp = lp_fn(x0)
    else:
        x0 = np.asarray(init, dtype=np.float64)
        if x0.ndim == 2 and n_walkers is not None and x0.shape[0] != W:
            raise ValueError(f"init has {x0.shape[0]} walkers but n_walkers = {W}")
        W = x0.shape[0] if x0.ndim == 2 else W
    lp0 = check_initial_state(post, x0, lp_fn)
    move_list = _moves(
        moves, (mean, cov) if moves == "laplace_de" and isinstance(init, tuple) else None
    )

    total = max_steps if n_steps is None else int(n_steps)
    if total < 1:
        raise ValueError(f"n_steps must be ≥ 1, got {n_steps}")
    thin_by = max(1, int(np.ceil(total / max_stored)))
    backend = None
    if backend_path is not None:
        backend = emcee.backends.HDFBackend(str(backend_path))
        backend.reset(W, d)
    sampler = emcee.EnsembleSampler(
        W, d, lp_fn, moves=move_list, vectorize=True, backend=backend,
        parameter_names=None,
    )  # fmt: skip
    state = emcee.State(x0, log_prob=lp0)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
    t0 = time.perf_counter()
    if n_steps is not None:
        sampler.run_mcmc(state, max(1, total // thin_by), thin_by=thin_by, progress=progress)
    else:
        chunk = max(1, check_every // thin_by)
        old_tau = np.inf
        bar = _adaptive_bar(progress, max_steps)  # ONE bar over all chunks (total: max_steps)
        while sampler.iteration * thin_by < max_steps:
            state = _run_chunk(sampler, state, chunk, thin_by, bar)
            it = sampler.iteration
            tau = np.nanmax(_autocorr(sampler, int(discard * it))) * thin_by
            kept = (it - int(discard * it)) * thin_by
            if np.isfinite(tau) and kept >= tau_multiple * tau and abs(old_tau - tau) < 0.05 * tau:
                break
            old_tau = tau
        if bar is not None:
            bar.total = bar.n  # stopped at 50 τ: the bar ends full
            bar.close()
    wall = time.perf_counter() - t0
    disc = int(discard * sampler.iteration)
    diag = _diagnostics(sampler, disc, thin_by, W, wall, moves, tau_multiple)
    diag["laplace"] = laplace_info
    if not diag["converged_50tau"]:
        warnings.warn(
            f"emcee chain is {diag['steps_over_tau']:.1f} autocorrelation times long (τ_max = "
            f"{diag['tau_max']:.0f} steps, {diag['n_steps'] - diag['discard_steps']} steps kept); "
            f"below {tau_multiple:g} τ the τ and ESS estimates are unreliable: run longer",
            ShortChainWarning,
            stacklevel=2,
        )
    # keep about two draws per autocorrelation time per walker (the rest is redundant)
    thin_out = max(1, int(diag["tau_max"] / thin_by / 2)) if np.isfinite(diag["tau_max"]) else 1
    diag["thin_output"] = int(thin_out * thin_by)
    chain = sampler.get_chain(discard=disc, thin=thin_out, flat=True)
    lps = sampler.get_log_prob(discard=disc, thin=thin_out, flat=True)
    theta, extra = post.split(chain)
    return PosteriorSamples(
        samples=np.concatenate([theta, extra], axis=1),
        log_prob=np.asarray(lps),
        scale=post.scale,
        n=post.n,
        names=tuple(param_names(post.n, post.kind if post.model_error else "none")),
        diagnostics=diag,
        predictive=post.predictive_data(),
    )


# --- files -----------------------------------------------------------------------------


def save_samples(path, ps: PosteriorSamples) -> Path:
    """Write samples to ``.npz`` (:func:`hapid.io.save_samples`: ``samples (S, d)``,
    ``log_prob (S,)``, ``n``, ``names``, ``omega_ref``, ``z_ref``, ``method``, diagnostics)."""
    from ..io import save_samples as _save

    return _save(path, ps)


def load_samples(path, n: int | None = None) -> PosteriorSamples:
    """Read a :func:`save_samples` file. ``n`` (optional): the rod count expected — a file
    for a different ``n``, or whose sample width does not match its ``n``, is a
    ``ValueError``."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"samples file {path} does not exist")
    from ..io import _numeric, _read_arrays, _scalar

    d = _read_arrays(path, "a posterior-samples file (hapid posterior)")
    missing = [k for k in ("samples", "log_prob", "n", "omega_ref", "z_ref", "names") if k not in d]
    if missing:
        raise ValueError(f"{path}: not a posterior-samples file (missing {missing})")
    file_n = _scalar(d, "n", path, integer=True)
    if file_n < 1:
        raise ValueError(f"{path}: n = {file_n} rods; expected n ≥ 1")
    s = _numeric(d, "samples", path)
    log_prob = _numeric(d, "log_prob", path)
    omega_ref, z_ref = _scalar(d, "omega_ref", path), _scalar(d, "z_ref", path)
    if n is not None and file_n != int(n):
        raise ValueError(
            f"{path}: samples are for an n = {file_n} rod device, but n = {n} was expected"
        )
    p = n_params(file_n)
    if s.ndim != 2 or s.shape[1] not in (p, p + 2, p + 6, p + 8, p + 10):
        raise ValueError(
            f"{path}: samples have shape {s.shape}, which does not fit n = {file_n} "
            f"(expected (S, {p}), (S, {p + 2}), (S, {p + 6}), (S, {p + 8}) or (S, {p + 10}))"
        )
    if not np.all(np.isfinite(s)):
        raise ValueError(f"{path}: samples contain NaN or inf")
    if s.shape[0] == 0 or log_prob.shape != (s.shape[0],):
        raise ValueError(
            f"{path}: {s.shape[0]} samples with log_prob of shape {log_prob.shape}; expected "
            f"≥ 1 sample and log_prob of shape ({s.shape[0]},)"
        )
    if not (np.all(np.isfinite(log_prob)) or np.all(np.isnan(log_prob))):  # all NaN: not evaluated
        raise ValueError(
            f"{path}: log_prob has NaN or inf entries; expected all finite (MCMC draws) or all "
            "NaN (draws whose density was not evaluated, e.g. Laplace)"
        )
    if not (np.isfinite(omega_ref) and omega_ref > 0 and np.isfinite(z_ref) and z_ref > 0):
        raise ValueError(f"{path}: omega_ref = {omega_ref:g}, z_ref = {z_ref:g}; expected both > 0")
    diag = {k[5:]: (v.item() if v.ndim == 0 else v) for k, v in d.items() if k.startswith("diag_")}
    diag["method"] = str(d["method"]) if "method" in d else ""
    return PosteriorSamples(
        samples=s,
        log_prob=log_prob,
        scale=Scale(jnp.asarray(omega_ref), jnp.asarray(z_ref)),
        n=file_n,
        names=tuple(str(x) for x in d["names"]),
        diagnostics=diag,
        predictive=_load_predictive(d, path, file_n) if "pred_kind" in d else None,
        measured=_load_measured(d, path, file_n) if "meas_omega" in d else None,
    )


def _load_measured(d: dict, path, n: int) -> dict:
    out = {k: np.asarray(d[f"meas_{k}"]) for k in ("omega", "Z_H", "Z_T") if f"meas_{k}" in d}
    K = np.shape(out.get("omega", ()))
    for k in ("Z_H", "Z_T"):
        if k not in out or np.shape(out[k]) != K + (n, n) or not np.all(np.isfinite(out[k])):
            raise ValueError(
                f"{path}: measured FRF {k!r} missing, not finite or not ({K[0] if K else 0}, {n}, {n})"
            )
    if len(K) != 1 or K[0] < 3 or np.any(np.diff(out["omega"]) <= 0) or out["omega"][0] <= 0:
        raise ValueError(f"{path}: measured FRF omega must be ≥ 3 increasing positive frequencies")
    return out


def _load_predictive(d: dict, path, n: int) -> dict:
    out = {k[5:]: v for k, v in d.items() if k.startswith("pred_")}
    out["kind"] = str(out["kind"])
    if "error_scale" in out:
        out["error_scale"] = str(out["error_scale"])
    N = np.shape(out.get("omega", ()))
    for k in ("Z_H", "Z_T", "var_H", "var_T"):
        if k not in out or np.shape(out[k]) != N + (n, n) or not np.all(np.isfinite(out[k])):
            raise ValueError(
                f"{path}: predictive data {k!r} missing or not finite ({N[0] if N else 0}, {n}, {n})"
            )
    return out
