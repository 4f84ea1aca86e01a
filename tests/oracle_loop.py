# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The LAPACK reference loop analysis: :func:`analyze_loop` → :class:`LoopReport`.

An independent check of the production verdict and metrics
(:func:`hapid.control.loop_metrics`, :func:`hapid.pipeline.loop`): the same stability rule
(:func:`hapid.control.nyquist_verdict`) decided on the grid with LAPACK's LU, SVD and
``eig`` — no screening, no refinement of the bandwidth or of the peaks (only the loci
margins, optionally on an exact ``L_fn``). Tests compare the production path with it;
benchmarks import it too (``sys.path`` gets ``tests/``).

Everything here is pure ``jnp`` on arrays ``(N, n, n)`` (frequency first), so it can be
``jit``-ed and ``vmap``-ed over a batch of plants or models. ``P`` may be any plant response
(a device's true P, a model's P̂, a measured FRF); ``G`` the controller response on the
same grid ``omega`` (rad/s, increasing, > 0). Conventions are the paper's: negative
feedback, ``L = P G``, ``T = (I + L)⁻¹ L`` (desired → interaction force), ``S = I − T``.

Stability is decided first (generalized Nyquist criterion, see :mod:`hapid.control._nyquist`).
An unstable loop — including one whose ``I + L`` is singular on the grid or whose phase the
grid does not resolve — reports ``stable=False`` and ``NaN`` for the bandwidths, the T peak
and ``0`` disk margin, never a plausible-looking number. The loci margins (GM/PM) are
reported for any loop, like python-control, since they describe the open loop.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Complex, Float

import hapid  # noqa: F401  (float64)
from hapid._constants import TWO_PI
from hapid._plain import enum_members, jsonable
from hapid.control import (
    LoopStatus,
    characteristic_loci,
    disk_margin_from_peak,
    isotropic_bandwidth,
    loci_margins,
    nyquist_encirclements,
    nyquist_verdict,
)
from hapid.control._lapack import after, lu_det_solve
from hapid.control._loop import loop_arrays, report_numbers

_SCALARS = (
    "stable",
    "n_encirclements",
    "n_closed_loop_rhp",
    "singular",
    "singular_hz",
    "nyquist_resolved",
    "iso_bandwidth_hz",
    "iso_bandwidth_literal_hz",
    "gm_db",
    "pm_deg",
    "gm_freq_hz",
    "pm_freq_hz",
    "disk_margin",
    "disk_gm_db",
    "disk_pm_deg",
    "t_peak_db",
    "t_peak_hz",
)


class LoopReport(eqx.Module):
    """Result of :func:`analyze_loop` (0-d arrays unless stated; frequencies in Hz).

    Verdict: ``stable`` (bool), ``n_encirclements`` (clockwise encirclements of the origin
    by det(I+L) over the full Nyquist contour; stable iff ``= −P_ol``), ``n_closed_loop_rhp``
    (``n_encirclements + P_ol``, closed-loop RHP poles), ``singular`` (I + L numerically
    singular at a grid frequency, i.e. a closed-loop pole on the imaginary axis) with
    ``singular_hz`` (first such frequency, NaN if none), ``nyquist_resolved`` (grid
    resolved the phase of det(I+L) and reached its real end values).

    Performance (NaN when not stable): ``iso_bandwidth_hz`` — lowest frequency where
    σ̄(T − I) reaches 1 − 1/√2 (log-frequency interpolation); ``iso_bandwidth_literal_hz`` —
    the paper's literal "maximum frequency where σ̄(T − I) < 1 − 1/√2" (the last upward
    crossing; equal to the former unless σ̄(T − I) dips back under the threshold). ``0``
    means the threshold is already exceeded at the first grid point, ``inf`` that it is
    never reached on the grid. ``t_peak_db``/``t_peak_hz``: max over ω of σ̄(T) (grid).

    Margins: ``gm_db``, ``gm_freq_hz``, ``pm_deg``, ``pm_freq_hz`` (worst over the loci; see
    :mod:`hapid.control._margins`); ``disk_margin`` (α = 2/max σ̄(S − T), 0 when not stable),
    ``disk_gm_db``, ``disk_pm_deg``.

    Arrays: ``freq_hz (N,)``, ``sv_T_minus_I (N, n)``, ``sv_L (N, n)``, ``cond_L (N,)``,
    ``loci (N, n)`` complex (tracked eigenvalues of L).
    """

    stable: Bool[Array, ""]
    n_encirclements: Float[Array, ""]
    n_closed_loop_rhp: Float[Array, ""]
    singular: Bool[Array, ""]
    singular_hz: Float[Array, ""]
    nyquist_resolved: Bool[Array, ""]
    iso_bandwidth_hz: Float[Array, ""]
    iso_bandwidth_literal_hz: Float[Array, ""]
    gm_db: Float[Array, ""]
    pm_deg: Float[Array, ""]
    gm_freq_hz: Float[Array, ""]
    pm_freq_hz: Float[Array, ""]
    disk_margin: Float[Array, ""]
    disk_gm_db: Float[Array, ""]
    disk_pm_deg: Float[Array, ""]
    t_peak_db: Float[Array, ""]
    t_peak_hz: Float[Array, ""]
    freq_hz: Float[Array, " N"]
    sv_T_minus_I: Float[Array, "N n"]
    sv_L: Float[Array, "N n"]
    cond_L: Float[Array, " N"]
    loci: Complex[Array, "N n"]

    @property
    def ok(self):
        """True when the closed loop is stable (bool array for a batch; works under ``jit``)."""
        return self.stable

    @property
    def status(self):
        """:class:`LoopStatus` ``STABLE``, ``UNSTABLE`` or ``UNRESOLVED`` (not stable and the
        grid did not resolve the Nyquist count); an object array of them for a batch."""
        st, res = np.asarray(self.stable), np.asarray(self.nyquist_resolved)
        return enum_members(np.where(st, "stable", np.where(res, "unstable", "unresolved")),
                            LoopStatus)  # fmt: skip

    def numbers(self) -> dict:
        """The scalar fields as python ``bool``/``int``/``float`` (lists for a batched report),
        ``stable`` first, then ``status`` (its value) and ``ok``; non-finite values stay
        ``nan``/``inf`` (for arithmetic; :meth:`summary` is the JSON form)."""
        return report_numbers(self, _SCALARS)

    def summary(self) -> dict:
        """Strict-JSON dict: :meth:`numbers` with non-finite values as ``None``."""
        return jsonable(self.numbers())


@eqx.filter_jit
def analyze_loop(
    P: Complex[Array, "N n n"],
    G: Complex[Array, "N n n"],
    omega: Float[Array, " N"],
    P_ol_rhp=0,
    *,
    L_fn: Callable | None = None,
    n_refine: int = 4,
    singular_rtol: float = 1e-9,
    max_phase_step: float = np.pi / 2,
    loci_method: str = "auto",
) -> LoopReport:
    """Analyze the negative-feedback loop ``L = P G`` on the grid ``omega`` (rad/s).

    Args:
        P, G: plant and controller responses ``(N, n, n)`` complex.
        omega: increasing positive frequencies (rad/s), ``(N,)``. Cover the dynamics: from
            well below the first to well above the last corner, densely enough to resolve
            the phase of det(I + L) (see :mod:`hapid.control._nyquist`).
        P_ol_rhp: number of open-loop poles of P and G in the open right half plane
            (int or 0-d array; the caller knows it — e.g. ``StateSpace.n_unstable_poles``,
            or the CRHP roots of Ẑ_H for the inverse-model controller).
        L_fn: optional callable ``omega (M,) -> L(jω) (M, n, n)`` for exact refinement of
            gain/phase crossovers (see :func:`hapid.control.loci_margins`).
        singular_rtol: ``I + L`` is flagged singular where σ̲(I+L) ≤ rtol·max(1, σ̄(I+L)).
        max_phase_step: largest allowed step of the unwrapped phase of det(I + L) (rad).
        loci_method: eigenvalue tracking, see :func:`hapid.control.track_loci`.

    Returns:
        :class:`LoopReport`. jit/vmap-able (``L_fn`` is static; use ``eqx.filter_jit``).
    """
    P, G, omega = loop_arrays(P, G, omega, "analyze_loop")
    n = P.shape[-1]
    eye = jnp.eye(n, dtype=jnp.complex128)

    L = P @ G
    IL = eye + L
    # One LU (det and S), then one batched SVD, then eig — strictly in sequence: concurrent
    # batched LAPACK kernels deadlock XLA:CPU with jaxlib 0.10.2 (see hapid.control._lapack).
    det, S = lu_det_solve(IL, jnp.broadcast_to(eye, L.shape))
    T = eye - S
    sv_all = jnp.linalg.svd(after(jnp.stack([IL, S, T, S - T, L]), det), compute_uv=False)
    sv_IL, sv_S, sv_T, sv_SmT, sv_L = sv_all
    sing_k = sv_IL[:, -1] <= singular_rtol * jnp.maximum(1.0, sv_IL[:, 0])
    singular = jnp.any(sing_k)
    singular_hz = jnp.where(singular, omega[jnp.argmax(sing_k)] / TWO_PI, jnp.nan)

    # --- stability first --------------------------------------------------------------
    n_enc, _, resolved = nyquist_encirclements(det, max_phase_step)
    p_ol = jnp.asarray(P_ol_rhp, dtype=jnp.float64)
    nan = jnp.nan

    # --- closed-loop maps (S = (I+L)⁻¹, T − I = −S) ----------------------------------
    # sv_S = σ(S) = σ(T − I)
    cond_L = sv_L[:, 0] / sv_L[:, -1]

    bw, bw_lit = isotropic_bandwidth(sv_S, omega)
    kpk = jnp.argmax(sv_T[:, 0])
    t_peak_db = 20.0 * jnp.log10(sv_T[kpk, 0])
    t_peak_hz = omega[kpk] / TWO_PI

    disk = disk_margin_from_peak(jnp.max(sv_SmT[:, 0]))

    # --- loci and margins -------------------------------------------------------------
    loci = characteristic_loci(after(L, sv_all), method=loci_method)
    mg = loci_margins(loci, omega, L_fn=L_fn, n_refine=n_refine)
    # det(I + L) hides two loci that each swing by π between grid points (a 2π step of its
    # phase unwraps to 0): every locus 1 + λ_i must be resolved too (tests/test_stress.py)
    dphi = jnp.diff(jnp.unwrap(jnp.angle(1.0 + loci), axis=0), axis=0)
    resolved = resolved & jnp.all(jnp.abs(dphi) < max_phase_step)
    stable = nyquist_verdict(n_enc, p_ol, resolved, singular)

    def if_stable(x, other=nan):
        return jnp.where(stable, x, other)

    return LoopReport(
        stable=stable,
        n_encirclements=n_enc,
        n_closed_loop_rhp=n_enc + p_ol,
        singular=singular,
        singular_hz=singular_hz,
        nyquist_resolved=resolved,
        iso_bandwidth_hz=if_stable(bw / TWO_PI),
        iso_bandwidth_literal_hz=if_stable(bw_lit / TWO_PI),
        gm_db=mg.gm_db,
        pm_deg=mg.pm_deg,
        gm_freq_hz=mg.gm_omega / TWO_PI,
        pm_freq_hz=mg.pm_omega / TWO_PI,
        disk_margin=if_stable(disk.disk_margin, 0.0),
        disk_gm_db=if_stable(disk.disk_gm_db, 0.0),
        disk_pm_deg=if_stable(disk.disk_pm_deg, 0.0),
        t_peak_db=if_stable(t_peak_db),
        t_peak_hz=if_stable(t_peak_hz),
        freq_hz=omega / TWO_PI,
        sv_T_minus_I=sv_S,
        sv_L=sv_L,
        cond_L=cond_L,
        loci=loci,
    )
