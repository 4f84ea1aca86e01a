# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The NLS fit's problem: data scaling, residual weights and the :class:`Problem` a solver
minimises (:func:`make_problem`); the names of the weights it accepts."""

from __future__ import annotations

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ..defaults import FIT_BAND_HZ
from ..frf import FRF
from ..impedance import plant
from ._checks import band_mask, check_fit_input
from ._pd import (
    Scale,
    n_params,
    scaled_pair,
    theta_to_scaled,
)
from ._wls import OMEGA_C_PAPER

WEIGHTS = ("relative", "paper", "noise", "blend")
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
