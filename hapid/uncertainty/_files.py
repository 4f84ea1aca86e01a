"""File-level helpers for the CLI (``hapid posterior``, ``hapid robust``): plain functions."""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..defaults import FIT_BAND_HZ
from ..io import load_frf, save_samples
from ..pipeline import control_fit
from ._laplace import posterior_laplace_samples
from ._likelihood import boundary_fixed
from ._loopgp import measured_data
from ._model_error import GP
from ._posterior import make_log_posterior
from ._sampler import sample_posterior


def posterior_from_files(
    frf_path,
    out_path,
    *,
    method: str = "emcee",
    n_samples: int = 4000,
    n_steps: int | None = None,
    seed: int = 0,
    progress: bool = True,
    backend_path=None,
    fit_options: dict | None = None,
    posterior_options: dict | None = None,
    sampler_options: dict | None = None,
    fix_boundary: bool = True,
    boundary_refit: bool = True,
):
    """FRF file → NLS fit (start point) → posterior samples file (``.npz``).

    The fit is ``hapid fit``'s, made by the same call: the FRF cut to ``0–f_max_hz`` and
    :func:`hapid.pipeline.control_fit` (relative weights, 40 Hz band by default; a fit
    whose inverse-model controller would be improper or marginal is refitted with
    ``pd_eps = PD_EPS`` unless ``boundary_refit`` is false, ``hapid posterior
    --keep-boundary``), so the posterior is built around the model ``hapid fit`` writes for
    the same FRF. ``fit_options`` are the pipeline's NLS options (``weight``, ``solver``,
    ``omega_c_hz``, ``max_steps``, ``f_max_hz``…). The draws' diagnostics record the fit:
    ``fit_pd_eps`` (the refit's floor, 0 without a refit), ``fit_theta`` (its θ, in the
    samples' scale: ``theta_to_model(fit_theta, scale)`` is the model) and ``fit_fixed``
    (the matrices held).

    ``method``: ``"emcee"`` (default; ``n_steps`` None = run to 50 τ) or ``"laplace"``
    (``n_samples`` draws of the posterior's Laplace Gaussian in matrix coordinates, projected
    onto the PSD cone: :func:`posterior_laplace_samples`); ``posterior_options`` go to
    ``make_log_posterior`` (its ``f_max_hz`` defaults to the fit's; a GP model error uses
    the NLS fit as the GP amplitudes' reference and as the start of the hyperparameters' mode
    search); with ``fix_boundary`` the fit's matrices at
    the PSD boundary are held fixed (:func:`boundary_fixed`) — after a refit those are the
    refit's strictly PD matrices (``L Lᵀ + pd_eps·I``, whose ``L Lᵀ`` part is on the
    boundary), so every draw keeps the refit's realizable controller there;
    ``sampler_options`` (``n_walkers``, ``moves``, ``max_steps``…) to ``sample_posterior``.
    Returns the :class:`PosteriorSamples`.
    """

    if method not in ("emcee", "laplace"):
        raise ValueError(f"method must be 'emcee' or 'laplace', got {method!r}")
    frf = load_frf(frf_path)
    fit_options = {"weight": "relative", "f_max_hz": FIT_BAND_HZ} | dict(fit_options or {})
    cf = posterior_fit(frf, boundary_refit=boundary_refit, **fit_options)
    nls, refit = cf.fit.result, cf.refit_pd_eps
    popts = {"f_max_hz": fit_options["f_max_hz"]} | dict(posterior_options or {})
    if fix_boundary and nls.boundary and "fixed" not in popts:
        popts["fixed"] = boundary_fixed(nls).held()
    if isinstance(popts.get("model_error"), GP):
        popts.setdefault("reference", nls)
    post = make_log_posterior(frf, nls.scale, **popts)
    if method == "laplace":
        ps = posterior_laplace_samples(post, int(n_samples), nls, key=seed)
    else:
        ps = sample_posterior(post, nls, n_steps=n_steps, seed=seed, progress=progress,
                              backend_path=backend_path, **dict(sampler_options or {}))  # fmt: skip
    fit_diag = {"fit_pd_eps": 0.0 if refit is None else float(refit),
                "fit_theta": np.asarray(nls.theta),
                "fit_fixed": np.asarray(sorted(popts.get("fixed") or ()), dtype=str)}  # fmt: skip
    ps = dataclasses.replace(ps, measured=measured_data(frf), diagnostics=ps.diagnostics | fit_diag)
    save_samples(out_path, ps)
    return ps


def posterior_fit(
    frf, *, f_max_hz: float | None = FIT_BAND_HZ, boundary_refit: bool = True, **options
):
    """The fit :func:`posterior_from_files` builds the posterior around — ``hapid fit``'s
    NLS fit, by the same call: ``frf`` cut to ``0–f_max_hz`` (Hz) and
    :func:`hapid.pipeline.control_fit` (``options``: its NLS options; the PSD-boundary refit
    unless ``boundary_refit`` is false). Returns the :class:`~hapid.pipeline.ControlFit`
    (``.fit.result`` the :class:`~hapid.fit.NLSResult`, ``.refit_pd_eps``); raises
    ``FitFailedError`` if the fit did not converge."""
    band = frf if f_max_hz is None else frf.band(0.0, float(f_max_hz))  # as hapid fit cuts it
    cf = control_fit(band, boundary_refit=boundary_refit, f_max_hz=None, **options)
    cf.fit.result.raise_if_failed()
    return cf
