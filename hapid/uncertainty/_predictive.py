# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Posterior-predictive credible bands of impedances and plants (vmapped over samples).

Quantities (each per frequency ω, ``(N, …)``; linear magnitudes, convert to dB yourself):

- ``"abs_Z_H"``, ``"abs_Z_T"`` — element magnitudes ``|Ẑ_ij|`` (``(N, n, n)``);
- ``"sv_Z_H"``, ``"sv_Z_T"`` — singular values, descending (``(N, n)``);
- ``"sv_P"`` — singular values of ``P̂ = Ẑ_H Ẑ_T⁻¹`` (``(N, n)``);
- ``"sv_P_Phatinv"`` — singular values of ``P P̂⁻¹`` with ``P = P_ref`` the measured or true
  plant (``(N, n)``; ``P_ref`` required). Its band around 0 dB is the paper's model-quality
  figure.

Band ``q`` levels are quantiles over the samples, per frequency and per index (singular
values are sorted per sample before the quantile, so the k-th band is the band of the k-th
largest singular value).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._linalg import svdvals
from ..fit._pd import theta_to_model
from ..impedance import plant
from ._sampler import PosteriorSamples

QUANTITIES = ("abs_Z_H", "abs_Z_T", "sv_Z_H", "sv_Z_T", "sv_P", "sv_P_Phatinv")


@eqx.filter_jit
def _chunk(theta, scale, s, P_ref, names):
    def one(t):
        m = theta_to_model(t, scale)
        ZH, ZT = m.hand(s), m.total(s)
        out = {}
        if "abs_Z_H" in names:
            out["abs_Z_H"] = jnp.abs(ZH)
        if "abs_Z_T" in names:
            out["abs_Z_T"] = jnp.abs(ZT)
        if "sv_Z_H" in names:
            out["sv_Z_H"] = svdvals(ZH)
        if "sv_Z_T" in names:
            out["sv_Z_T"] = svdvals(ZT)
        if "sv_P" in names:
            out["sv_P"] = svdvals(plant(ZH, ZT))
        if "sv_P_Phatinv" in names:
            # P P̂⁻¹ = P Ẑ_T Ẑ_H⁻¹
            out["sv_P_Phatinv"] = svdvals(plant(P_ref @ ZT, ZH))
        return out

    return jax.vmap(one)(theta)


def predictive_samples(
    ps: PosteriorSamples, omega, quantities=("sv_Z_H", "sv_Z_T", "sv_P"), P_ref=None,
    chunk: int = 500, max_samples: int | None = 2000, seed: int = 0,
) -> dict[str, np.ndarray]:  # fmt: skip
    """Per-sample quantities ``{name: (S', N, …)}`` on ``omega`` (rad/s), computed in chunks.

    At most ``max_samples`` samples are used (a random subset, ``seed``); ``None`` = all.
    """
    names = tuple(quantities)
    bad = [q for q in names if q not in QUANTITIES]
    if bad:
        raise ValueError(f"unknown quantities {bad}; choose from {QUANTITIES}")
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if omega.ndim != 1:
        raise ValueError(f"omega must be (N,), got shape {omega.shape}")
    if "sv_P_Phatinv" in names:
        if P_ref is None:
            raise ValueError("sv_P_Phatinv needs P_ref (N, n, n): the measured or true plant")
        P_ref = jnp.asarray(P_ref, dtype=jnp.complex128)
        if P_ref.shape != (omega.shape[0], ps.n, ps.n):
            raise ValueError(f"P_ref must be ({omega.shape[0]}, {ps.n}, {ps.n}), got {P_ref.shape}")
    else:
        P_ref = jnp.zeros((1, 1, 1), dtype=jnp.complex128)
    theta = ps.theta
    if max_samples is not None and theta.shape[0] > max_samples:
        idx = np.random.default_rng(seed).choice(theta.shape[0], max_samples, replace=False)
        theta = theta[np.sort(idx)]
    s = 1j * omega
    parts = [
        _chunk(jnp.asarray(theta[i : i + chunk]), ps.scale, s, P_ref, names)
        for i in range(0, theta.shape[0], chunk)
    ]
    return {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in names}


def credible_bands(
    ps: PosteriorSamples, omega, quantities=("sv_Z_H", "sv_Z_T", "sv_P"), P_ref=None,
    q=(0.05, 0.5, 0.95), chunk: int = 500, max_samples: int | None = 2000, seed: int = 0,
) -> dict[str, np.ndarray]:  # fmt: skip
    """Credible bands ``{name: (len(q), N, …)}`` of the quantities (module docstring) over
    the posterior samples, on ``omega`` (rad/s). Default levels 5/50/95 %."""
    qs = np.asarray(q, dtype=float)
    if np.any((qs < 0) | (qs > 1)):
        raise ValueError(f"quantile levels must be in [0, 1], got {q}")
    per = predictive_samples(ps, omega, quantities, P_ref, chunk, max_samples, seed)
    return {k: np.quantile(v, qs, axis=0) for k, v in per.items()}
