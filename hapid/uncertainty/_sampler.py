# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The emcee driver.

:func:`sample_posterior` runs ``emcee.EnsembleSampler`` with ``vectorize=True`` on the jitted,
vmapped log-posterior, its walkers drawn from the Laplace approximation
(:func:`~hapid.uncertainty._laplace.laplace_posterior`; full draws need no burn-in); optional
HDF5 backend, tqdm progress bar, autocorrelation time, effective sample size, and a
:class:`ShortChainWarning` below 50 τ. Moves: :data:`MOVES`, ``DEMove()`` by default
(the ESS-per-second comparison is in benchmarks/bench_uncertainty.py and docs/conventions.md).
"""

from __future__ import annotations

import logging
import time
import warnings
from pathlib import Path

import emcee
import jax
import numpy as np
from tqdm.auto import tqdm

from .. import _config  # noqa: F401  (float64)
from ..fit._result import NLSResult
from ..samples import PosteriorSamples
from ._laplace import _mvn, laplace_posterior
from ._likelihood import (
    LogPosterior,
    batched_log_prob,
    param_names,
)
from ._mode import (
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
        lp = laplace_posterior(post, initial_point(post, init))
        init, laplace_info = (lp.mean, lp.cov), lp.info()
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
        names=tuple(param_names(post.n, post.error)),
        diagnostics=diag,
        predictive=post.predictive_data(),
    )
