# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Building a :class:`~hapid.uncertainty._likelihood.LogPosterior` from an FRF.

:func:`make_log_posterior` checks the FRF, sets up the scale, the model-error term and its
hyperparameters (fixed at the marginal mode for ``gp_corr``, at the joint mode for ``gp``,
or sampled), and returns the posterior. It composes the likelihood
(:mod:`~hapid.uncertainty._likelihood`) with the mode search (:mod:`~hapid.uncertainty._mode`).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..defaults import FIT_BAND_HZ
from ..fit._pd import MATRIX_NAMES, Scale, n_params
from ..fit._result import NLSResult
from ..frf import FRF
from ._coords import fold_theta
from ._gp import N_GP_CORR_HYPER
from ._hyper import GP_HYPER_MODES, fix_gp_hyper, marginal_hyper
from ._likelihood import (
    DEFAULT_LOG_ELL_MEAN,
    DEFAULT_LOG_ELL_SD,
    DEFAULT_LOG_TAU_MEAN,
    DEFAULT_LOG_TAU_SD,
    DEFAULT_PRIOR_SCALE,
    GP_KINDS,
    PARAMETERIZATIONS,
    LogPosterior,
    error_kind,
)
from ._mode import initial_point, posterior_mode
from ._weights import ERROR_SCALES, N_CLASS_HYPER, element_weights


def make_log_posterior(
    frf: FRF,
    scale: Scale | None = None,
    *,
    f_max_hz: float | None = FIT_BAND_HZ,
    model_error: bool | str = True,
    noise_corr: float = 0.0,
    prior_scale: float = DEFAULT_PRIOR_SCALE,
    log_tau_mean: float = DEFAULT_LOG_TAU_MEAN,
    log_tau_sd: float = DEFAULT_LOG_TAU_SD,
    parameterization: str = "matrix",
    fixed: dict | None = None,
    reference=None,
    log_ell_mean: float = DEFAULT_LOG_ELL_MEAN,
    log_ell_sd: float = DEFAULT_LOG_ELL_SD,
    gp_hyper=None,
    warp: bool = True,
    error_scale: str = "shared",
) -> LogPosterior:
    """Build the :class:`LogPosterior` of ``frf`` (module docstring for the model).

    - ``scale``: the units of θ; pass ``nls_result.scale`` so the NLS θ is a starting point
      (default: ``hapid.fit.data_scale(frf, f_max_hz)``, the same as ``fit_nls`` uses).
    - ``f_max_hz``: only frequencies ``≤ f_max_hz`` enter (default 40 Hz like ``fit_nls``;
      ``None`` = all).
    - ``model_error``: ``"white"`` (or ``True``, default): relative model-error scales
      ``log τ_H, log τ_M``, independent per frequency; ``"gp"``: the model error of each
      element is a smooth random function of log-frequency (a Matérn-5/2 Gaussian process
      with amplitudes ``τ_H a_H(ω), τ_M a_M(ω)`` (data RMS element sizes) and learned length scales ``ℓ_H, ℓ_M``,
      marginalized in closed form: :func:`gp_covariance`); ``"gp_corr"``: the same with the
      hand and mechanism errors of each element *correlated* through a shared latent
      function (complex correlation ρ, two more hyperparameters ``rho_re, rho_im``), in
      the frequency coordinate ``asinh(ω/ω_c)`` (linear below a learned knee ω_c, log above;
      the κ slots hold ``log(ω_c/ω_ref)``: :func:`corr_warp`, :func:`gp_corr_blocks`,
      :func:`gp_corr_covariance`); ``"none"`` (or
      ``False``): pure measurement noise — then the FRF's stds must be > 0 everywhere.
    - ``reference`` (gp only, required): an :class:`~hapid.fit.NLSResult` or its θ (Cholesky,
      ``scale`` units): the shape of the GP amplitude outside the fit band
      (:func:`gp_amplitudes`; inside it, the data's RMS element sizes as for ``"white"``).
    - ``log_ell_mean``, ``log_ell_sd``: prior of ``log ℓ`` (ℓ in natural-log frequency
      units; default median 0.5, i.e. a factor e^0.5 ≈ 1.65 in frequency, sd 1). The
      amplitude slopes have the prior ``β ~ N(0, 1)``.
    - ``gp_hyper`` (gp kinds only; None = ``"map"`` for gp, ``"marginal"`` for gp_corr):
      ``"map"`` (empirical Bayes) — the hyperparameters are held at their posterior mode
      (joint with θ, from the NLS start: ``reference`` must then be the NLSResult) and the
      log-likelihood becomes an exact quadratic form in the matrix entries
      (:func:`fix_gp_hyper`; ~100× cheaper per evaluation, only θ sampled); ``"marginal"`` —
      held at the mode of their *marginal* posterior, the matrices integrated out in closed
      form (:func:`marginal_hyper`; type-II maximum likelihood: the joint mode's θ absorbs
      part of the misfit and under-covers), then the same quadratic form; ``"sample"`` — the
      hyperparameters are sampled with θ (``d = p + 8`` or ``p + 10``; each evaluation
      factors ``n²`` covariances of ``2N × 2N``); or the numbers (6: κ = 0, 8, or 10 for
      gp_corr) — held at those values.
    - ``warp`` (gp only): learn the Box–Cox warps κ of log-frequency (:func:`warp`; default
      True); False: κ ≡ 0 (stationary in log-frequency). Held-out coverage of P
      (benchmarks/calibrate_predictive.py, Laplace): learned κ 0.89 / 0.90 / 1.00 on cu5 /
      tripod3 + 2 ms / hexapod6 + 2 ms, κ ≡ 0 0.91 / 0.91 / 0.80.
    - ``error_scale`` (gp_corr only): ``"shared"`` (default) — every element's error has the
      amplitude ``τ a(ω)`` (the RMS element size); ``"element"`` — element ``(i, j)`` has
      ``τ a(ω) w_ij(ω)`` with ``w_ij`` proportional to the size ``|K_ij| + ω|B_ij| + ω²|M_ij|``
      of the reference model's element (:func:`element_weights`; a relative error per
      element, no new hyperparameter, same closed-form likelihood); ``"class"`` — element
      ``(i, j)`` has ``τ a(ω) w_ij`` with ``w = 1`` on the diagonal and ``e^γ`` off it
      (RMS 1; :func:`class_weights`), ``γ_H, γ_M`` learned at the marginal mode with the other
      hyperparameters (``gp_hyper`` must be ``"marginal"`` or 12 numbers, the last two γ); then
      the weights are held like ``"element"``'s. Not calibrated on every device
      (docs/conventions.md "Posterior").
    - ``noise_corr``: correlation ρ ∈ (−1, 1) of the Z_H/Z_T measurement errors per element.
    - ``prior_scale``, ``log_tau_mean``, ``log_tau_sd``: the priors.
    - ``parameterization``: ``"matrix"`` (default; matrix entries on the PSD cone) or
      ``"cholesky"`` (the NLS fit's factors); module docstring.
    - ``fixed``: ``{name: (n, n) matrix in physical units}`` for matrices of
      ``M_H, B_H, K_H, M_M, B_M, K_M`` held at a value rather than sampled (the posterior
      *conditional* on them; matrix parameterization only). :func:`boundary_fixed` gives the
      NLS fit's matrices at the PSD boundary — e.g. ``K_M ≈ 0`` on a mechanism without
      stiffness, where the cone-truncated posterior of that matrix is nearly all boundary and
      makes ensemble moves crawl.

    Raises ``ValueError`` for a missing std, non-finite data, fewer than 3 band frequencies,
    zero std without ``model_error``, or bad options.
    """
    from ..fit._problem import data_scale

    if not isinstance(frf, FRF):
        raise ValueError(f"make_log_posterior: expected an FRF, got {type(frf).__name__}")
    if frf.Z_H_std is None or frf.Z_T_std is None:
        raise ValueError(
            "make_log_posterior: the FRF has no Z_H_std/Z_T_std; the likelihood needs the noise "
            "level (estimate the FRF from ≥ 2 periods)"
        )
    if np.ndim(frf.omega) != 1:
        raise ValueError("make_log_posterior: a single (unbatched) FRF is required")
    if parameterization not in PARAMETERIZATIONS:
        raise ValueError(
            f"parameterization must be one of {PARAMETERIZATIONS}, got {parameterization!r}"
        )
    if not (-1.0 < noise_corr < 1.0):
        raise ValueError(f"noise_corr must be in (-1, 1), got {noise_corr}")
    if not (prior_scale > 0 and log_tau_sd > 0 and np.isfinite(log_tau_mean)):
        raise ValueError("prior_scale and log_tau_sd must be > 0 and log_tau_mean finite")
    band = frf if f_max_hz is None else frf.band(0.0, f_max_hz)
    if band.omega.shape[0] < 3:
        raise ValueError(
            f"make_log_posterior: only {band.omega.shape[0]} frequencies ≤ f_max_hz={f_max_hz} Hz"
        )
    for name in ("Z_H", "Z_T", "Z_H_std", "Z_T_std"):
        a = np.asarray(getattr(band, name))
        if not np.all(np.isfinite(a)):
            raise ValueError(f"make_log_posterior: FRF {name} contains NaN or inf")
    kind = error_kind(model_error)
    model_error = kind != "none"
    if error_scale not in ERROR_SCALES:
        raise ValueError(f"error_scale must be one of {ERROR_SCALES}, got {error_scale!r}")
    if error_scale != "shared" and kind != "gp_corr":
        raise ValueError(f"error_scale={error_scale!r} needs model_error='gp_corr'")
    if not (log_ell_sd > 0 and np.isfinite(log_ell_mean)):
        raise ValueError("log_ell_sd must be > 0 and log_ell_mean finite")
    if not model_error:
        for name in ("Z_H_std", "Z_T_std"):
            if np.any(np.asarray(getattr(band, name)) <= 0):
                raise ValueError(
                    f"make_log_posterior: FRF {name} has zero entries; a pure-noise likelihood "
                    "needs std > 0 everywhere (use model_error=True for a relative floor)"
                )
    scale = data_scale(frf, f_max_hz) if scale is None else scale
    zr = scale.z_ref
    n = frf.n
    theta_fixed, free_idx = None, ()
    if fixed:
        if parameterization != "matrix":
            raise ValueError("fixed matrices need parameterization='matrix'")
        unknown = set(fixed) - set(MATRIX_NAMES)
        if unknown:
            raise ValueError(f"fixed: unknown matrix names {sorted(unknown)}; use {MATRIX_NAMES}")
        t = n * (n + 1) // 2
        rows, cols = np.tril_indices(n)
        fac = [float(np.asarray(f)) for f in scale.factors()]
        th = np.zeros(n_params(n))
        for name, A in fixed.items():
            A = np.asarray(A, dtype=np.float64)
            if A.shape != (n, n) or not np.all(np.isfinite(A)):
                raise ValueError(
                    f"fixed[{name!r}] must be a finite ({n}, {n}) matrix, got shape {A.shape}"
                )
            k = MATRIX_NAMES.index(name)
            th[k * t : (k + 1) * t] = (0.5 * (A + A.T) * fac[k % 3])[rows, cols]
        blocks = [MATRIX_NAMES.index(nm) for nm in fixed]
        free_idx = tuple(i for i in range(n_params(n)) if i // t not in blocks)
        theta_fixed = jnp.asarray(th)
    Z_H, Z_T = band.Z_H / zr, band.Z_T / zr
    rms = lambda Z: jnp.linalg.norm(Z, axis=(-2, -1)) / n  # noqa: E731
    a_H, a_M, ref_theta = rms(Z_H), rms(Z_T - Z_H), None
    w_H = w_M = None
    if kind in GP_KINDS:
        ref_theta = _reference_theta(reference, scale, n)
        if error_scale == "element":
            w_H, w_M = (jnp.asarray(w) for w in element_weights(ref_theta, scale, band.omega))
    post = LogPosterior(
        s=1j * band.omega / scale.omega_ref,
        Z_H=Z_H,
        Z_T=Z_T,
        var_H=(band.Z_H_std / zr) ** 2,
        var_T=(band.Z_T_std / zr) ** 2,
        a_H=a_H,
        a_M=a_M,
        scale=scale,
        model_error=bool(model_error),
        noise_corr=float(noise_corr),
        prior_scale=float(prior_scale),
        log_tau_mean=float(log_tau_mean),
        log_tau_sd=float(log_tau_sd),
        parameterization=parameterization,
        theta_fixed=theta_fixed,
        free_idx=free_idx,
        kind=kind,
        ref_theta=ref_theta,
        log_ell_mean=float(log_ell_mean),
        log_ell_sd=float(log_ell_sd),
        warp=bool(warp),
        w_H=w_H,
        w_M=w_M,
        error_scale=error_scale,
    )
    if gp_hyper is None:  # the defaults: joint mode for gp, marginal mode for gp_corr
        gp_hyper = "marginal" if kind == "gp_corr" else "map"
    if error_scale == "class" and isinstance(gp_hyper, str) and gp_hyper != "marginal":
        raise ValueError("error_scale='class' learns γ at the marginal mode: gp_hyper must be "
                         f"'marginal' or {N_CLASS_HYPER} numbers, got {gp_hyper!r}")  # fmt: skip
    if kind not in GP_KINDS or (isinstance(gp_hyper, str) and gp_hyper == "sample"):
        return post
    if isinstance(gp_hyper, str) and gp_hyper == "marginal":
        h0 = jnp.asarray(post.hyper_mean())
        if error_scale == "class":
            h0 = jnp.concatenate([h0, jnp.zeros(N_CLASS_HYPER - N_GP_CORR_HYPER)])
        gp_hyper, _ = marginal_hyper(post, h0)
        return fix_gp_hyper(post, gp_hyper)
    if isinstance(gp_hyper, str):
        if gp_hyper != "map":
            raise ValueError(f"gp_hyper must be one of {GP_HYPER_MODES} or 8 numbers, got "
                             f"{gp_hyper!r}")  # fmt: skip
        if not isinstance(reference, NLSResult):
            raise ValueError("gp_hyper='map' needs reference= the NLSResult (the start of the "
                             "mode search); pass gp_hyper='sample' or 6 fixed values otherwise")  # fmt: skip
        xm, _ = posterior_mode(post, initial_point(post, reference))
        gp_hyper = xm[post.n_free :]
    return fix_gp_hyper(post, gp_hyper)


def _reference_theta(reference, scale: Scale, n: int):
    if reference is None:
        raise ValueError("model_error='gp' needs reference= (the NLS result or its θ): the GP "
                         "amplitudes are the reference model's element sizes")  # fmt: skip
    if isinstance(reference, NLSResult):
        if not (np.allclose(np.asarray(reference.scale.z_ref), np.asarray(scale.z_ref))
                and np.allclose(np.asarray(reference.scale.omega_ref), np.asarray(scale.omega_ref))):  # fmt: skip
            raise ValueError("reference: the NLS result's scale differs from the posterior's")
        reference = reference.theta
    th = np.asarray(reference, dtype=np.float64)
    if th.shape != (n_params(n),) or not np.all(np.isfinite(th)):
        raise ValueError(f"reference θ must be finite with shape ({n_params(n)},), got {th.shape}")
    return jnp.asarray(fold_theta(th))
