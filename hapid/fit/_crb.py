# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The Cramér–Rao bound of the sample-ML fit (:func:`cramer_rao`) and the P·P̂⁻¹ band it
implies (:func:`crb_band_db`, dB, from Gaussian draws of the parameters)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..defaults import FIT_BAND_HZ, PPHAT_BAND_HZ
from ..experiment import Run, estimate_frf
from ..impedance import ImpedanceModel, singular_values
from ._checks import TWO_PI
from ._diagnostics import PPhatBand
from ._ml import _sym_to_vec, _vec_to_sym, make_ml_problem, run_spectra
from ._nls import pinv_psd
from ._pd import (
    Scale,
    model_to_scaled,
    model_to_theta,
    scaled_to_model,
)
from ._problem import data_scale


class CramerRao(NamedTuple):
    """The Cramér–Rao bound of a model for a run's noise (:func:`cramer_rao`).

    - ``crb``: ``(p, p)``, the bound on the covariance of the model's parameters in matrix
      coordinates (see :class:`~hapid.fit.MLResult`), in ``scale`` units — what
      :func:`crb_band_db` takes.
    - ``scale``: the :class:`~hapid.fit.Scale` (ω_ref rad/s, z_ref N/m) of those coordinates.
    """

    crb: Float[Array, "p p"]
    scale: Scale


def cramer_rao(run: Run, model: ImpedanceModel, *, f_max_hz: float | None = FIT_BAND_HZ,
               scale: Scale | None = None) -> CramerRao:  # fmt: skip
    """:class:`CramerRao` ``(crb, scale)``: the Cramér–Rao bound (matrix coordinates, see
    :class:`MLResult`) of the second-order model at ``model`` for the noise of ``run`` — for
    any fit's model (WLS, NLS, ML); ``scale`` defaults to the NLS data scale of the run's
    FRF."""
    spectra = run_spectra(run, f_max_hz)
    if scale is None:
        scale = data_scale(estimate_frf(run), f_max_hz)
    theta = model_to_theta(model, scale)
    problem = make_ml_problem(spectra, scale, model_floor=0.0)
    return CramerRao(pinv_psd(problem.fisher_matrices(theta)), scale)


def _band_draws(model, cov, scale, omega, n_draws, seed):
    """Draws of the (min, max) dB of σ(P(θ̂)·P̂⁻¹) with ``P̂⁻¹`` linearized at the model."""
    n = model.n
    s = 1j * jnp.asarray(omega)
    v0 = _sym_to_vec(model_to_scaled(model, scale))
    P0 = model.P(s)

    def pinv_flat(v):
        Pi = scaled_to_model(_vec_to_sym(v, n), scale).P_inv(s)
        return jnp.concatenate([jnp.real(Pi).ravel(), jnp.imag(Pi).ravel()])

    G = jax.jacfwd(pinv_flat)(v0)  # (2·N·n², p)
    cov = np.asarray(cov)
    lam, V = np.linalg.eigh(0.5 * (cov + cov.T))
    root = jnp.asarray(V * np.sqrt(np.maximum(lam, 0.0)))
    z = jnp.asarray(np.random.default_rng(seed).standard_normal((n_draws, root.shape[0])))
    d = (G @ root @ z.T).T  # (draws, 2·N·n²)
    half = d.shape[1] // 2
    dPi = (d[:, :half] + 1j * d[:, half:]).reshape((n_draws,) + P0.shape)
    db = 20.0 * jnp.log10(singular_values(jnp.eye(n) + P0 @ dPi))
    return np.asarray(jnp.min(db, axis=(1, 2))), np.asarray(jnp.max(db, axis=(1, 2)))


def crb_band_db(
    model: ImpedanceModel,
    crb,
    scale: Scale,
    omega,
    *,
    f_max_hz: float = PPHAT_BAND_HZ,
    n_draws: int = 200,
    seed: int = 0,
    quantile: float = 0.5,
) -> PPhatBand:
    """The P·P̂⁻¹ band an efficient estimator reaches at this noise level (:class:`PPhatBand`
    of floats).

    ``crb``: the Cramér–Rao bound in matrix coordinates at ``model`` (``MLResult.crb`` or
    :func:`cramer_rao`), in ``scale`` units. Draws ``δv ~ N(0, crb)`` and, with ``P̂⁻¹``
    linearized at ``model``, the singular values of ``P(v̂)(P̂⁻¹(v̂) + ∂P̂⁻¹ δv)`` (dB) over
    ``omega`` ≤ ``f_max_hz`` (rad/s grid, Hz limit). Returns the ``quantile`` (default
    median) over draws of the lower band edge taken from below and of the upper edge from
    above: ``(lo_db ≤ 0, hi_db ≥ 0)``.
    """
    omega = np.asarray(omega)
    keep = omega <= TWO_PI * f_max_hz * (1 + 1e-12)
    if not keep.any():
        raise ValueError(f"crb_band_db: no frequencies ≤ {f_max_hz} Hz")
    lo, hi = _band_draws(model, crb, scale, omega[keep], n_draws, seed)
    return PPhatBand(float(np.quantile(lo, 1 - quantile)), float(np.quantile(hi, quantile)))
