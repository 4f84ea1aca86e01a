# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""Pure diagnostics of a fitted model against data (paper section 4.3).

``P`` arguments are ``(N, n, n)`` complex plant arrays — the empirical ``FRF.P`` or a true
plant — on the angular frequencies ``omega`` (``(N,)``, rad/s). ``f_max_hz`` limits a
summary to frequencies ≤ f_max_hz (Hz).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .._constants import TWO_PI
from ..defaults import PPHAT_BAND_HZ
from ..frf import FRF
from ..impedance import ImpedanceModel, singular_values
from ._checks import is_concrete


class ImpedanceSV(NamedTuple):
    """Singular values ``(N, n)`` of the data and of the model, for Z_H and Z_T."""

    Z_H: Float[Array, "N n"]
    Z_H_hat: Float[Array, "N n"]
    Z_T: Float[Array, "N n"]
    Z_T_hat: Float[Array, "N n"]


def impedance_singular_values(frf: FRF, model: ImpedanceModel) -> ImpedanceSV:
    """Singular values of Z vs Ẑ per frequency (paper Figs. 6–7), N/m."""
    return ImpedanceSV(
        Z_H=singular_values(frf.Z_H),
        Z_H_hat=singular_values(model.hand.at_omega(frf.omega)),
        Z_T=singular_values(frf.Z_T),
        Z_T_hat=singular_values(model.total.at_omega(frf.omega)),
    )


def pphat(P: Complex[Array, "N n n"], model: ImpedanceModel, omega: Float[Array, " N"]):
    """``P(jω) P̂⁻¹(jω)`` (``(N, n, n)``), ideally the identity."""
    return P @ model.P_inv(1j * jnp.asarray(omega))


def pphat_singular_values(
    P: Complex[Array, "N n n"], model: ImpedanceModel, omega: Float[Array, " N"]
) -> Float[Array, "N n"]:
    """Singular values of ``P P̂⁻¹`` per frequency (paper Fig. 8), linear (not dB)."""
    return singular_values(pphat(P, model, omega))


class PPhatBand(NamedTuple):
    """The band of the singular values of ``P P̂⁻¹`` over a frequency range, dB:
    ``lo_db`` the lowest (≤ 0 for a band around the identity), ``hi_db`` the highest.

    0-d arrays from :func:`pphat_band_db` (jittable), floats from
    :func:`~hapid.fit.crb_band_db`. Unpacks as ``lo, hi = band``.
    """

    lo_db: Float[Array, ""] | float
    hi_db: Float[Array, ""] | float


class AnisotropyReduction(NamedTuple):
    """The range over frequencies of span(P) / span(P P̂⁻¹) (:func:`anisotropy_reduction`),
    span = σ̄/σ̲ as a ratio (not dB): ``lo`` the smallest factor, ``hi`` the largest (0-d
    arrays, jittable). Unpacks as ``lo, hi = red``."""

    lo: Float[Array, ""]
    hi: Float[Array, ""]


def _band(omega, f_max_hz):
    mask = jnp.asarray(omega) <= TWO_PI * f_max_hz * (1 + 1e-12)
    if is_concrete(omega, f_max_hz) and not np.any(np.asarray(mask)):
        raise ValueError(f"no frequencies at or below f_max_hz={f_max_hz} Hz")
    return mask


def pphat_band_db(
    P: Complex[Array, "N n n"],
    model: ImpedanceModel,
    omega: Float[Array, " N"],
    f_max_hz: float = PPHAT_BAND_HZ,
) -> PPhatBand:
    """:class:`PPhatBand` ``(lo_db, hi_db)``: min and max dB over all singular values of
    ``P P̂⁻¹`` at frequencies ≤ f_max_hz (jittable; an empty band is an error when ``omega``
    and ``f_max_hz`` are concrete).

    The paper reports about ±7 dB up to 30 Hz for its WLS model.
    """
    mask = _band(omega, f_max_hz)[:, None]
    db = 20.0 * jnp.log10(pphat_singular_values(P, model, omega))
    return PPhatBand(jnp.min(jnp.where(mask, db, jnp.inf)), jnp.max(jnp.where(mask, db, -jnp.inf)))


def anisotropy_reduction(
    P: Complex[Array, "N n n"],
    model: ImpedanceModel,
    omega: Float[Array, " N"],
    f_max_hz: float = PPHAT_BAND_HZ,
) -> AnisotropyReduction:
    """:class:`AnisotropyReduction` ``(lo, hi)``: min and max over frequencies ≤ f_max_hz of
    span(P) / span(P P̂⁻¹).

    span = σ̄/σ̲ as a ratio (not dB). The paper: plant span 25–50 dB, reduced "by a factor of
    8 to 140" up to 30 Hz.
    """
    mask = _band(omega, f_max_hz)
    sp = singular_values(P)
    sq = pphat_singular_values(P, model, omega)
    ratio = (sp[:, 0] / sp[:, -1]) / (sq[:, 0] / sq[:, -1])
    return AnisotropyReduction(
        jnp.min(jnp.where(mask, ratio, jnp.inf)), jnp.max(jnp.where(mask, ratio, -jnp.inf))
    )


def model_relative_errors(model: ImpedanceModel, truth: ImpedanceModel) -> Float[Array, " 6"]:
    """Relative Frobenius errors ``‖Â − A‖/‖A‖`` of M_H, B_H, K_H, M_T, B_T, K_T (``(6,)``)."""
    est = (model.hand.M, model.hand.B, model.hand.K, model.total.M, model.total.B, model.total.K)
    tru = (truth.hand.M, truth.hand.B, truth.hand.K, truth.total.M, truth.total.B, truth.total.K)
    return jnp.stack(
        [
            jnp.linalg.norm(a - b, axis=(-2, -1)) / jnp.linalg.norm(b, axis=(-2, -1))
            for a, b in zip(est, tru, strict=True)
        ],
        axis=-1,
    )
