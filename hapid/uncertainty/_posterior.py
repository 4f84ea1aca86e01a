# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Building a :class:`~hapid.uncertainty._likelihood.LogPosterior` from an FRF.

:func:`make_log_posterior` checks the FRF, sets up the scale and the model-error term, and
fixes the model error's hyperparameters as the model-error object says
(:func:`~hapid.uncertainty._hyper.fix_hyperparameters`, its own step).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..defaults import FIT_BAND_HZ
from ..fit._pd import MATRIX_NAMES, Scale, n_params
from ..fit._problem import data_scale
from ..fit._result import NLSResult
from ..frf import FRF
from ._coords import fold_theta
from ._hyper import fix_hyperparameters
from ._likelihood import DEFAULT_PRIOR_SCALE, FixedMatrices, LogPosterior
from ._model_error import GP, GPCorr, ModelError, White, as_model_error
from ._weights import element_weights


def make_log_posterior(
    frf: FRF,
    scale: Scale | None = None,
    *,
    f_max_hz: float | None = FIT_BAND_HZ,
    model_error: ModelError | None = None,
    noise_corr: float = 0.0,
    prior_scale: float = DEFAULT_PRIOR_SCALE,
    fixed: FixedMatrices | dict | None = None,
    reference=None,
) -> LogPosterior:
    """Build the :class:`LogPosterior` of ``frf`` (module docstring for the model).

    - ``scale``: the units of θ; pass ``nls_result.scale`` so the NLS θ is a starting point
      (default: ``hapid.fit.data_scale(frf, f_max_hz)``, the same as ``fit_nls`` uses).
    - ``f_max_hz``: only frequencies ``≤ f_max_hz`` enter (default
      :data:`hapid.defaults.FIT_BAND_HZ`; ``None`` = all).
    - ``model_error``: the model-error strategy — :class:`NoError` (pure measurement noise:
      the FRF's stds must then be > 0 everywhere), :class:`White` (``None``: the default
      ``White()``), :class:`GP` or
      :class:`GPCorr` (``hapid posterior``'s default), each with its priors and, for the GP
      kinds, how its hyperparameters are fixed (:func:`fix_hyperparameters`).
    - ``reference`` (GP kinds, required): an :class:`~hapid.fit.NLSResult` or its θ
      (Cholesky, ``scale`` units): the shape of the GP amplitude outside the fit band, and
      for ``hyper="map"`` the NLSResult is the start of the mode search.
    - ``noise_corr``: correlation ρ ∈ (−1, 1) of the Z_H/Z_T measurement errors per element.
    - ``prior_scale``: the sd of the matrix entries' prior (scaled units).
    - ``fixed``: a :class:`FixedMatrices` or ``{name: (n, n) matrix in physical units}`` for
      matrices of ``M_H, B_H, K_H, M_M, B_M, K_M`` held at a value rather than sampled (the
      posterior *conditional* on them). :func:`boundary_fixed` gives the NLS fit's matrices at
      the PSD boundary — e.g. ``K_M ≈ 0`` on a mechanism without stiffness, where the cone-truncated
      posterior of that matrix is nearly all boundary and makes ensemble moves crawl.

    Raises ``ValueError`` for a missing std, non-finite data, fewer than 3 band frequencies,
    zero std without model error, or bad options.
    """
    error = White() if model_error is None else as_model_error(model_error)
    if not isinstance(frf, FRF):
        raise ValueError(f"make_log_posterior: expected an FRF, got {type(frf).__name__}")
    if frf.Z_H_std is None or frf.Z_T_std is None:
        raise ValueError(
            "make_log_posterior: the FRF has no Z_H_std/Z_T_std; the likelihood needs the noise "
            "level (estimate the FRF from ≥ 2 periods)"
        )
    if np.ndim(frf.omega) != 1:
        raise ValueError("make_log_posterior: a single (unbatched) FRF is required")
    if not (-1.0 < noise_corr < 1.0):
        raise ValueError(f"noise_corr must be in (-1, 1), got {noise_corr}")
    if not prior_scale > 0:
        raise ValueError("prior_scale must be > 0")
    band = frf if f_max_hz is None else frf.band(0.0, f_max_hz)
    if band.omega.shape[0] < 3:
        raise ValueError(
            f"make_log_posterior: only {band.omega.shape[0]} frequencies ≤ f_max_hz={f_max_hz} Hz"
        )
    for name in ("Z_H", "Z_T", "Z_H_std", "Z_T_std"):
        a = np.asarray(getattr(band, name))
        if not np.all(np.isfinite(a)):
            raise ValueError(f"make_log_posterior: FRF {name} contains NaN or inf")
    if error.n_hyper == 0:
        for name in ("Z_H_std", "Z_T_std"):
            if np.any(np.asarray(getattr(band, name)) <= 0):
                raise ValueError(
                    f"make_log_posterior: FRF {name} has zero entries; a pure-noise likelihood "
                    "needs std > 0 everywhere (use model_error=White() for a relative floor)"
                )
    scale = data_scale(frf, f_max_hz) if scale is None else scale
    zr = scale.z_ref
    n = frf.n
    theta_fixed, free_idx = _fixed_entries(fixed, scale, n)
    Z_H, Z_T = band.Z_H / zr, band.Z_T / zr
    rms = lambda Z: jnp.linalg.norm(Z, axis=(-2, -1)) / n  # noqa: E731
    a_H, a_M, ref_theta = rms(Z_H), rms(Z_T - Z_H), None
    w_H = w_M = None
    if isinstance(error, GP):
        ref_theta = _reference_theta(reference, scale, n)
        if isinstance(error, GPCorr) and error.scale == "element":
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
        error=error,
        noise_corr=float(noise_corr),
        prior_scale=float(prior_scale),
        theta_fixed=theta_fixed,
        free_idx=free_idx,
        ref_theta=ref_theta,
        w_H=w_H,
        w_M=w_M,
    )
    return fix_hyperparameters(post, reference)


def _fixed_entries(fixed: FixedMatrices | dict | None, scale: Scale, n: int):
    """``(theta_fixed (p,) | None, free_idx)`` of the matrices held by ``fixed``."""
    if isinstance(fixed, FixedMatrices):
        fixed = fixed.held()
    if not fixed:
        return None, ()
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
    return jnp.asarray(th), free_idx


def _reference_theta(reference, scale: Scale, n: int):
    if reference is None:
        raise ValueError("a GP model error needs reference= (the NLS result or its θ): the GP "
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
