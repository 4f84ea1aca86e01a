# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Gain, phase and disk margins from characteristic loci on a frequency grid.

Per locus ``λ_i(jω)`` (see :mod:`._nyquist`):

* phase crossover: ``λ_i`` crosses the negative real axis (``Im λ_i`` changes sign with
  ``Re λ_i < 0``); the gain margin there is ``GM = 1/|λ_i|``, ``gm_db = −20 log10 |λ_i|``;
* gain crossover: ``|λ_i| = 1``; the phase margin is ``PM = (∠λ_i mod 360°) − 180°``.

The reported margin is the worst over loci and crossings, chosen as python-control's
``stability_margins`` does for SISO loops: the GM closest to 0 dB (``min |gm_db|``, so a
lower gain margin of a conditionally stable loop is negative dB) and the PM of smallest
magnitude. No crossing → ``inf`` with frequency ``NaN``.

On the grid, crossings are interpolated linearly within a grid interval (in log ω). Given
a callable ``L_fn(omega) -> (M, n, n)`` the ``n_refine`` worst grid candidates are refined
by bisection (60 halvings of the log-frequency bracket, the locus followed by nearest
eigenvalue), which makes margins and crossover frequencies exact to rounding.

Disk margin (Seiler, Packard & Gahinet 2020, "An introduction to disk margins", IEEE
Control Systems Magazine 40(5)): the balanced (skew σ = 0) disk margin of a SISO loop is
``α = 2/‖S − T‖∞`` with ``S = (1+L)⁻¹``, ``T = L(1+L)⁻¹``; the loop tolerates every gain
and phase variation ``f = (1 + α/2 δ)/(1 − α/2 δ)``, ``|δ| ≤ 1``, i.e. simultaneous gain in
``[(2−α)/(2+α), (2+α)/(2−α)]`` or phase ``±2 arctan(α/2)``. For MIMO loops this module uses
``σ̄(S − T)`` — a full (unstructured) complex perturbation at the loop's output — which is
conservative for independent loop-at-a-time (diagonal) variations. On a grid the peak of
``σ̄(S − T)`` may be missed between points, so α is slightly optimistic for coarse grids.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from ._lapack import after

_DB = 20.0 / np.log(10.0)
_BISECT_STEPS = 60


class LociMargins(NamedTuple):
    """Worst gain and phase margins over the characteristic loci (:func:`loci_margins`);
    each a 0-d float array (a leading batch axis under ``vmap``).

    ``gm_db``: gain margin (dB) closest to 0 dB, ``inf`` without a phase crossover;
    ``gm_omega``: its frequency (rad/s), ``NaN`` without one; ``pm_deg``: phase margin (deg)
    of smallest magnitude, ``inf`` without a gain crossover; ``pm_omega``: its frequency
    (rad/s), ``NaN`` without one.
    """

    gm_db: Array
    gm_omega: Array
    pm_deg: Array
    pm_omega: Array


class DiskMargin(NamedTuple):
    """Balanced disk margin and the gain/phase variations it tolerates
    (:func:`disk_margin_from_peak`); each a 0-d float array, shaped like the peak.

    ``disk_margin``: α = 2/‖S − T‖∞ (dimensionless); ``disk_gm_db``: 20 log10((2+α)/(2−α))
    in dB (``inf`` for α ≥ 2); ``disk_pm_deg``: 2 arctan(α/2) in degrees.
    """

    disk_margin: Array
    disk_gm_db: Array
    disk_pm_deg: Array


def _interp_log_omega(omega, k, t):
    lw = jnp.log(omega)
    return jnp.exp(lw[k] + t * (lw[k + 1] - lw[k]))


def phase_crossing(a, b):
    """Crossing of the negative real axis by loci moving from ``a`` to ``b`` (same shape,
    complex): ``(valid, t, gm_db)`` — crossing fraction ``t`` ∈ [0, 1] by linear
    interpolation of Im, ``valid`` where Im changes sign with Re < 0 there, and the gain
    margin (dB) from the log-interpolated |λ|."""
    ia, ib = jnp.imag(a), jnp.imag(b)
    change = (ia >= 0) != (ib >= 0)
    den = jnp.where(change, ia - ib, 1.0)
    t = jnp.clip(jnp.where(change, ia / den, 0.0), 0.0, 1.0)
    re = jnp.real(a) + t * (jnp.real(b) - jnp.real(a))
    la, lb = jnp.log(jnp.abs(a)), jnp.log(jnp.abs(b))
    return change & (re < 0), t, -_DB * (la + t * (lb - la))


def gain_crossing(a, b):
    """Crossing of the unit circle by loci moving from ``a`` to ``b``: ``(change, t, pm_deg)``
    — ``t`` by linear interpolation of log|λ|, the phase margin of the interpolated λ."""
    fa, fb = jnp.log(jnp.abs(a)), jnp.log(jnp.abs(b))
    change = (fa >= 0) != (fb >= 0)
    den = jnp.where(change, fa - fb, 1.0)
    t = jnp.clip(jnp.where(change, fa / den, 0.0), 0.0, 1.0)
    return change, t, _pm_deg(a + t * (b - a))


def _phase_crossings(loci, omega):
    """Grid candidates: (valid (N−1,n), t, gm_db, omega_c)."""
    a, b = loci[:-1], loci[1:]
    valid, t, gm_db = phase_crossing(a, b)
    k = jnp.arange(a.shape[0])[:, None]
    w = _interp_log_omega(omega, k, t)
    return valid, gm_db, w


def _gain_crossings(loci, omega):
    a, b = loci[:-1], loci[1:]
    change, t, pm = gain_crossing(a, b)
    k = jnp.arange(a.shape[0])[:, None]
    w = _interp_log_omega(omega, k, t)
    return change, pm, w


def _pm_deg(lam):
    return jnp.remainder(jnp.angle(lam, deg=True), 360.0) - 180.0


def _nearest(eigs, ref):
    return eigs[jnp.argmin(jnp.abs(eigs - ref))]


def _refine(L_fn, lw_a, lw_b, lam_a, lam_b, f):
    """Bisection in log ω on ``f(λ)`` (a real function whose sign changes on [a, b])."""

    def eig_at(lw, ref):
        e = jnp.linalg.eigvals(L_fn(jnp.exp(lw)[None]))[0]
        return _nearest(e, ref)

    fa0 = f(lam_a)

    def body(_, c):
        lo, hi, la, lb = c
        mid = 0.5 * (lo + hi)
        lm = eig_at(mid, 0.5 * (la + lb))
        same = (f(lm) >= 0) == (fa0 >= 0)
        return (
            jnp.where(same, mid, lo),
            jnp.where(same, hi, mid),
            jnp.where(same, lm, la),
            jnp.where(same, lb, lm),
        )

    lo, hi, la, lb = jax.lax.fori_loop(0, _BISECT_STEPS, body, (lw_a, lw_b, lam_a, lam_b))
    mid = 0.5 * (lo + hi)
    return jnp.exp(mid), eig_at(mid, 0.5 * (la + lb))


def _pick(score, n_refine):
    flat = score.ravel()
    order = jnp.argsort(flat)[:n_refine]
    return order


def loci_margins(
    loci: Complex[Array, "N n"],
    omega: Float[Array, " N"],
    L_fn: Callable | None = None,
    n_refine: int = 4,
) -> LociMargins:
    """Worst gain and phase margins over all characteristic loci ``(N, n)`` on the grid
    ``omega`` (rad/s, ``(N,)``).

    Returns a :class:`LociMargins` of 0-d arrays: ``gm_db``, ``gm_omega`` (rad/s),
    ``pm_deg``, ``pm_omega`` (rad/s). ``L_fn`` (optional) maps ω ``(M,)`` rad/s to ``L(jω)`` ``(M, n, n)`` for exact
    refinement of the ``n_refine`` worst grid candidates of each kind.
    """
    N, n = loci.shape
    lw = jnp.log(omega)
    pvalid, gm_db, gm_w = _phase_crossings(loci, omega)
    gvalid, pm, pm_w = _gain_crossings(loci, omega)
    gscore = jnp.where(pvalid, jnp.abs(gm_db), jnp.inf)
    pscore = jnp.where(gvalid, jnp.abs(pm), jnp.inf)

    if L_fn is not None and N > 1:
        kk = min(n_refine, (N - 1) * n)

        def refine_set(score, f):
            idx = _pick(score, kk)
            k, i = idx // n, idx % n
            w, lam = jax.vmap(
                lambda k_, i_: _refine(L_fn, lw[k_], lw[k_ + 1], loci[k_, i_], loci[k_ + 1, i_], f)
            )(k, i)
            return idx, w, lam

        idx, w, lam = refine_set(gscore, jnp.imag)
        ok = jnp.isfinite(gscore.ravel()[idx]) & (jnp.real(lam) < 0)
        g_val = jnp.where(ok, -_DB * jnp.log(jnp.abs(lam)), jnp.inf)
        j = jnp.argmin(jnp.abs(g_val))
        gm_out, gm_w_out = g_val[j], jnp.where(ok[j], w[j], jnp.nan)

        pscore = after(pscore, lam)  # one LAPACK batch at a time (see ._lapack)
        idx, w, lam = refine_set(pscore, lambda x: jnp.log(jnp.abs(x)))
        ok = jnp.isfinite(pscore.ravel()[idx])
        p_val = jnp.where(ok, _pm_deg(lam), jnp.inf)
        j = jnp.argmin(jnp.abs(p_val))
        pm_out, pm_w_out = p_val[j], jnp.where(ok[j], w[j], jnp.nan)
    else:
        j = jnp.argmin(gscore.ravel())
        anyg = jnp.isfinite(gscore.ravel()[j])
        gm_out = jnp.where(anyg, gm_db.ravel()[j], jnp.inf)
        gm_w_out = jnp.where(anyg, gm_w.ravel()[j], jnp.nan)
        j = jnp.argmin(pscore.ravel())
        anyp = jnp.isfinite(pscore.ravel()[j])
        pm_out = jnp.where(anyp, pm.ravel()[j], jnp.inf)
        pm_w_out = jnp.where(anyp, pm_w.ravel()[j], jnp.nan)
    return LociMargins(gm_db=gm_out, gm_omega=gm_w_out, pm_deg=pm_out, pm_omega=pm_w_out)


def disk_margin_from_peak(peak_sv_S_minus_T: Float[Array, ""]) -> DiskMargin:
    """Balanced disk margin ``α = 2/‖S − T‖∞`` and its gain (dB) and phase (deg) margins,
    as a :class:`DiskMargin`, from the peak ``‖S − T‖∞`` (0-d, or any shape: elementwise).

    ``disk_gm_db = 20 log10((2+α)/(2−α))`` (``inf`` for α ≥ 2) and
    ``disk_pm_deg = 2 arctan(α/2)`` in degrees.
    """
    alpha = 2.0 / peak_sv_S_minus_T
    gm = jnp.where(
        alpha < 2.0, _DB * jnp.log((2.0 + alpha) / jnp.maximum(2.0 - alpha, 1e-300)), jnp.inf
    )
    pm = jnp.degrees(2.0 * jnp.arctan(alpha / 2.0))
    return DiskMargin(disk_margin=alpha, disk_gm_db=gm, disk_pm_deg=pm)
