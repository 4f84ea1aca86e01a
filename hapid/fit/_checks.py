# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""Input checks and the fit band shared by WLS and NLS.

Value checks (finite data, enough frequencies in the band, non-singular Z) run only on
concrete arrays, i.e. when a fit is called outside ``jit``/``vmap``; under a transform the
shapes are still checked and the band is applied as a 0/1 mask so shapes stay static.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._constants import TWO_PI
from ..frf import FRF


def is_concrete(*xs) -> bool:
    return all(x is None or not isinstance(x, jax.core.Tracer) for x in xs)


def band_mask(omega: Float[Array, " N"], f_max_hz: float | None) -> Float[Array, " N"]:
    """1.0 for frequencies ``≤ f_max_hz`` (all when ``None``), else 0.0; shape ``(N,)``."""
    if f_max_hz is None:
        return jnp.ones_like(omega)
    return (omega <= TWO_PI * jnp.asarray(f_max_hz) * (1 + 1e-12)).astype(omega.dtype)


def check_fit_input(
    frf: FRF,
    f_max_hz: float | None,
    *,
    need_std: bool = False,
    positive_std: bool = True,
    need_invertible_Z: bool = False,
    what: str = "fit",
) -> None:
    """Raise ``ValueError`` naming the problem; value checks only on concrete input."""
    if not isinstance(frf, FRF):
        raise ValueError(f"{what}: expected an FRF, got {type(frf).__name__}")
    if need_std and (frf.Z_H_std is None or frf.Z_T_std is None):
        raise ValueError(
            f"{what}: these weights need the FRF's Z_H_std and Z_T_std, which are missing"
        )
    if f_max_hz is not None and is_concrete(f_max_hz) and not f_max_hz > 0:
        raise ValueError(f"{what}: f_max_hz must be > 0 or None, got {f_max_hz}")
    arrays = (frf.omega, frf.Z_H, frf.Z_T, frf.Z_H_std, frf.Z_T_std)
    if not is_concrete(*arrays):
        return
    for name, a in zip(("omega", "Z_H", "Z_T", "Z_H_std", "Z_T_std"), arrays, strict=True):
        if a is not None and not np.all(np.isfinite(np.asarray(a))):
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(np.asarray(a)))[0])
            raise ValueError(f"{what}: FRF {name} contains NaN or inf (first at index {bad})")
    if need_std and positive_std:
        for name, a in (("Z_H_std", frf.Z_H_std), ("Z_T_std", frf.Z_T_std)):
            if np.any(np.asarray(a) <= 0):
                raise ValueError(f"{what}: FRF {name} must be > 0 everywhere for noise weights")
    w = np.asarray(frf.omega)
    if not is_concrete(f_max_hz):
        return
    mask = np.ones(w.shape, bool) if f_max_hz is None else w <= TWO_PI * f_max_hz * (1 + 1e-12)
    n_in = mask.sum(axis=-1)
    if np.any(n_in < 3):
        raise ValueError(
            f"{what}: only {int(np.min(n_in))} frequencies at or below f_max_hz={f_max_hz} Hz; "
            "a second-order fit needs at least 3 (raise f_max_hz)"
        )
    if need_invertible_Z:
        for name, Z in (("Z_T", frf.Z_T), ("Z_H", frf.Z_H)):
            c = np.linalg.cond(np.asarray(Z))
            bad = (c > 1e12) | ~np.isfinite(c)
            bad = bad & np.broadcast_to(mask, bad.shape)
            if np.any(bad):
                k = tuple(int(i) for i in np.argwhere(bad)[0])
                f = float(np.asarray(frf.omega)[k] / TWO_PI) if np.ndim(frf.omega) else 0.0
                raise ValueError(
                    f"{what}: FRF {name} is singular (condition number {c[k]:.3g}) at "
                    f"{f:.4g} Hz (index {k}); the P residual needs Z_H and Z_T invertible"
                )
