# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The inverse-model MIMO controller ``G(s) = g(s) Ẑ_T(s) Ẑ_H(s)⁻¹`` and the SISO baseline.

Frequency responses are ``(N, n, n)`` complex on ω in rad/s. The continuous realization
follows the paper (section 5): with ``y = Ẑ_H⁻¹ g R_E``,

    ÿ = M̂_H⁻¹ (g R_E − B̂_H ẏ − K̂_H y),     R_A = M̂_T ÿ + B̂_T ẏ + K̂_T y,

g realized in state space per channel and cascaded in front. Realizability (paper 5.1):
roots of det Ẑ_H in the closed right half plane are poles of G — the controller is
unstable (its frequency response cannot be measured before the loop is closed); CRHP roots
of det Ẑ_T are zeros of G (non-minimum phase, limits bandwidth).
"""

from __future__ import annotations

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Complex, Float

from .. import _config  # noqa: F401  (float64)
from ..defaults import GM_DB, PM_DEG
from ..impedance import ImpedanceModel
from ..lti import StateSpace, block_diag, series
from ._compensator import Compensator
from ._lapack import after
from ._margins import _gain_crossings, _phase_crossings
from ._nyquist import characteristic_loci, nyquist_encirclements
from ._status import ControllerStatus


class ControllerWarning(UserWarning):
    """The designed controller is unstable or non-minimum phase."""


def _g_response(g, omega):
    if isinstance(g, Compensator):
        return g.at_omega(omega)
    return jnp.asarray(g, dtype=jnp.complex128)


def inverse_model_response(
    model: ImpedanceModel, g: Compensator, omega: Float[Array, " N"]
) -> Complex[Array, "N n n"]:
    """``G(jω) = g(jω) Ẑ_T(jω) Ẑ_H(jω)⁻¹`` on ω (rad/s), ``(N, n, n)``."""
    omega = jnp.asarray(omega, dtype=jnp.float64)
    return _g_response(g, omega)[:, None, None] * model.P_inv(1j * omega)


def siso_response(
    g: Compensator, omega: Float[Array, " N"], n: int, c: float = 1.0
) -> Complex[Array, "N n n"]:
    """SISO baseline ``G(jω) = c g(jω) I_n`` (decentralized, identical loops)."""
    omega = jnp.asarray(omega, dtype=jnp.float64)
    return (c * _g_response(g, omega))[:, None, None] * jnp.eye(n)


def impedance_ratio_state_space(model: ImpedanceModel) -> StateSpace:
    """Realization of ``Ẑ_T(s) Ẑ_H(s)⁻¹`` (w → R_A) with state ``[y; ẏ]`` (``2n`` states).

    ``A = [[0, I], [−M̂_H⁻¹K̂_H, −M̂_H⁻¹B̂_H]]``, ``B = [0; M̂_H⁻¹]``,
    ``C = [K̂_T − M̂_T M̂_H⁻¹ K̂_H, B̂_T − M̂_T M̂_H⁻¹ B̂_H]``, ``D = M̂_T M̂_H⁻¹``.
    Requires a non-singular M̂_H. The poles are the roots of det Ẑ_H.
    """
    H, T = model.hand, model.total
    n = model.n
    MiK = jnp.linalg.solve(H.M, H.K)
    MiB = jnp.linalg.solve(H.M, H.B)
    Mi = jnp.linalg.inv(H.M)
    A = jnp.block([[jnp.zeros((n, n)), jnp.eye(n)], [-MiK, -MiB]])
    B = jnp.concatenate([jnp.zeros((n, n)), Mi], axis=0)
    D = T.M @ Mi
    C = jnp.concatenate([T.K - T.M @ MiK, T.B - T.M @ MiB], axis=1)
    return StateSpace(A, B, C, D)


def inverse_model_state_space(model: ImpedanceModel, g: Compensator) -> StateSpace:
    """Continuous realization of ``G(s) = g(s) Ẑ_T Ẑ_H⁻¹`` (input R_E, output R_A).

    States ``[x_g (n·order(g)); y (n); ẏ (n)]``; g is applied per channel (block diagonal).
    """
    return series(block_diag(g.state_space(), model.n), impedance_ratio_state_space(model))


@eqx.filter_jit
def controller_unstable_poles(
    model: ImpedanceModel, g: Compensator | None = None, tol: float = 0.0
):
    """Number of poles of G in the open RHP (``Re > tol``): roots of det Ẑ_H there, plus
    unstable poles of g. Pass it (plus the plant's) as ``p_ol`` to :func:`~hapid.control.loop_metrics`.
    One compiled program (jit; traced inline under an outer jit/vmap)."""
    n = jnp.sum(jnp.real(model.hand.roots()) > tol)
    if g is not None:
        n = n + g.state_space().n_unstable_poles(tol)
    return n


def controller_is_stable(
    model: ImpedanceModel, g: Compensator | None = None, tol: float = 0.0
) -> Bool[Array, ""]:
    """``True`` iff every pole of G has ``Re < −tol``: all roots of det Ẑ_H (and poles of g)
    strictly in the left half plane. A singular M̂_H (roots at infinity) counts as unstable.
    Jittable; see :func:`check_controller` for the warning and details."""
    roots = model.hand.roots()
    ok = jnp.all(jnp.isfinite(roots)) & jnp.all(jnp.real(roots) < -tol)
    if g is not None:
        ok = ok & g.state_space().is_stable(tol)
    return ok


class ControllerCheck(eqx.Module):
    """Verdict of :func:`check_controller`. Counts are closed-RHP (``Re ≥ −tol``) roots."""

    stable: bool
    minimum_phase: bool
    n_crhp_hand_roots: int
    n_crhp_total_roots: int
    hand_roots: Complex[Array, " 2n"]
    total_roots: Complex[Array, " 2n"]

    @property
    def ok(self) -> bool:
        """The controller is realizable as the paper requires: stable and minimum phase."""
        return bool(self.stable) and bool(self.minimum_phase)

    @property
    def status(self) -> ControllerStatus:
        """:class:`ControllerStatus`: ``OK``, ``UNSTABLE``, ``NON_MINIMUM_PHASE`` or
        ``UNSTABLE_NON_MINIMUM_PHASE``."""
        bad = [
            w
            for w, good in (("unstable", self.stable), ("non-minimum-phase", self.minimum_phase))
            if not good
        ]
        return ControllerStatus(", ".join(bad) or "ok")

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok`` and the closed-RHP root counts."""
        return {"status": self.status.value, "ok": self.ok, "stable": bool(self.stable),
                "minimum_phase": bool(self.minimum_phase), "n_crhp_hand_roots": int(self.n_crhp_hand_roots),
                "n_crhp_total_roots": int(self.n_crhp_total_roots)}  # fmt: skip


def check_controller(
    model: ImpedanceModel, g: Compensator | None = None, tol: float = 0.0, warn: bool = True
) -> ControllerCheck:
    """Realizability verdict of the inverse-model controller (paper 5.1), at the edge.

    Warns :class:`ControllerWarning` when det Ẑ_H has closed-RHP roots (G unstable) or
    det Ẑ_T has (G non-minimum phase). Not jittable (python values and warnings).
    """
    hr = np.asarray(model.hand.roots())
    tr = np.asarray(model.total.roots())
    bad_h = int(np.sum(~np.isfinite(hr)) + np.sum(np.real(hr[np.isfinite(hr)]) >= -tol))
    bad_t = int(np.sum(~np.isfinite(tr)) + np.sum(np.real(tr[np.isfinite(tr)]) >= -tol))
    g_ok = True if g is None else bool(g.state_space().is_stable(tol))
    stable = bad_h == 0 and g_ok
    if warn and not stable:
        warnings.warn(
            f"inverse-model controller is UNSTABLE: det Ẑ_H has {bad_h} root(s) in the closed "
            "right half plane (they are poles of G = g Ẑ_T Ẑ_H⁻¹; paper section 5.1)"
            + ("" if g_ok else " and g(s) has unstable poles")
            + ". Its frequency response cannot be measured open loop; refit with a PD "
            "parameterization or new data.",
            ControllerWarning,
            stacklevel=2,
        )
    if warn and bad_t:
        warnings.warn(
            f"inverse-model controller is non-minimum phase: det Ẑ_T has {bad_t} closed-RHP "
            "root(s) (zeros of G; paper section 5.1).",
            ControllerWarning,
            stacklevel=2,
        )
    return ControllerCheck(
        stable=stable,
        minimum_phase=bad_t == 0,
        n_crhp_hand_roots=bad_h,
        n_crhp_total_roots=bad_t,
        hand_roots=jnp.asarray(hr),
        total_roots=jnp.asarray(tr),
    )


# --- SISO gain design ---------------------------------------------------------------


def _feasible(loci, det_fn, c, omega, p_ol, gm_db, pm_deg):
    l = c * loci
    n_enc, _, resolved = nyquist_encirclements(det_fn(c))
    stable = (n_enc == -p_ol) & resolved
    pv, gm, _ = _phase_crossings(l, omega)
    gv, pm, _ = _gain_crossings(l, omega)
    gm_ok = jnp.all(jnp.where(pv, jnp.abs(gm) >= gm_db, True))
    pm_ok = jnp.all(jnp.where(gv, jnp.abs(pm) >= pm_deg, True))
    return stable & gm_ok & pm_ok


@eqx.filter_jit
def max_siso_gain(
    P: Complex[Array, "N n n"],
    omega: Float[Array, " N"],
    g,
    gm_db: float = GM_DB,
    pm_deg: float = PM_DEG,
    P_ol_rhp=0,
    n_scan: int = 241,
    decades: float = 8.0,
) -> Float[Array, ""]:
    """Largest ``c`` such that the loop ``L = c g P`` (controller ``c g(s) I``) is stable and
    every characteristic locus has ``|GM| ≥ gm_db`` dB and ``|PM| ≥ pm_deg`` degrees.

    ``g`` is a :class:`Compensator` or its response ``(N,)`` on ``omega`` (rad/s). The loci
    of ``c g P`` are ``c`` times those of ``g P``, so they are tracked once. ``c`` is scanned
    on ``n_scan`` log-spaced values over ``decades`` decades upward from
    ``c₀ = 10^(−gm_db/20) / (2 max_ω max_i |λ_i(g P)|)`` (loop gain below the GM
    requirement everywhere), then the boundary after the largest feasible scan point is
    refined by 60 bisection steps in log c. Returns ``NaN`` when no scanned ``c`` is
    feasible, the top of the scan range when that is still feasible. ``P_ol_rhp`` counts
    the open-loop RHP poles of P (and g). Margins are from the grid (no refinement): use a
    fine grid.
    """
    omega = jnp.asarray(omega, dtype=jnp.float64)
    P = jnp.asarray(P, dtype=jnp.complex128)
    n = P.shape[-1]
    gP = _g_response(g, omega)[:, None, None] * P
    loci = characteristic_loci(gP)
    p_ol = jnp.asarray(P_ol_rhp, dtype=jnp.float64)
    eye = jnp.eye(n)

    gP_det = after(gP, loci)  # LU only after eig (see ._lapack)

    def det_fn(c):
        return jnp.linalg.det(eye + c * gP_det)

    def feas(logc):
        return _feasible(loci, det_fn, 10.0**logc, omega, p_ol, gm_db, pm_deg)

    lc0 = -gm_db / 20.0 - jnp.log10(2.0 * jnp.max(jnp.abs(loci)))
    grid = lc0 + jnp.linspace(0.0, decades, n_scan)
    ok = jax.vmap(feas)(grid)
    k = n_scan - 1 - jnp.argmax(ok[::-1])  # largest feasible scan point
    any_ok = jnp.any(ok)
    top = k == n_scan - 1
    lo, hi = grid[k], grid[jnp.minimum(k + 1, n_scan - 1)]

    def body(_, c):
        lo, hi = c
        mid = 0.5 * (lo + hi)
        f = feas(mid)
        return jnp.where(f, mid, lo), jnp.where(f, hi, mid)

    lo, hi = jax.lax.fori_loop(0, 60, body, (lo, hi))
    c = jnp.where(top, 10.0 ** grid[-1], 10.0**lo)
    return jnp.where(any_ok, c, jnp.nan)
