# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Linear time-invariant systems: the one state space, its interconnections and discretizations.

A :class:`StateSpace` ``(A, B, C, D)`` realizes ``H(s) = C (sI − A)⁻¹ B + D`` (continuous,
``ts=None``, time in s, ``s`` in rad/s) or ``H(z) = C (zI − A)⁻¹ B + D`` (discrete, sampling
period ``ts`` in s, ``x[k+1] = A x[k] + B u[k]``). Shapes: ``A (nx, nx)``, ``B (nx, m)``,
``C (p, nx)``, ``D (p, m)``; leading batch dimensions are allowed for ``vmap`` in the
frequency response. The device models (:mod:`hapid.device`) and the controllers
(:mod:`hapid.control`) both use this class and the functions below.

Discretizations (``ts`` in s; all differentiable and jittable):

* :func:`zoh` — exact zero-order hold (``A_d = e^{A t_s}``, ``B_d = ∫₀^{t_s} e^{Aτ} dτ B``,
  one matrix exponential of ``[[A, B], [0, 0]]``): exact for a held (piecewise-constant) input.
* :func:`tustin` — bilinear ``s = (2/h)(z − 1)/(z + 1)``, ``h = t_s`` or prewarped to be
  exact at ``prewarp`` rad/s. Maps the open left half plane onto the open unit disc, so the
  discrete system is stable iff the continuous one is; exact at DC.
* :func:`matched` — matched pole-zero of the scalar compensator g (section by section: every
  pole and finite zero maps by ``z = e^{s t_s}``; the zeros at ``s = ∞`` map to ``z = −1``,
  all but one of them, or none — see ``infinite_zeros``; DC gain matched per section).
  :func:`matched_response` evaluates the same discrete g in closed form on a frequency grid
  (no state-space realization; cheaper inside an optimizer's gradient).

Interconnections: :func:`series` (cascade), :func:`feedback` (negative feedback
``u = G (r − y)``, ``y = P u``) and the closed-loop poles derived from it, the independent
cross-check of the generalized-Nyquist verdict of :func:`hapid.control.loop_metrics`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from jaxtyping import Array, Bool, Complex, Float, Int

from . import _config  # noqa: F401  (float64)

INFINITE_ZEROS = ("minus_one", "all_but_one", "delay")


class StateSpace(eqx.Module):
    """A real LTI system ``ẋ = A x + B u`` (``ts=None``) or ``x[k+1] = A x[k] + B u[k]``
    (sampling period ``ts`` s), with ``y = C x + D u``."""

    A: Float[Array, "... nx nx"]
    B: Float[Array, "... nx m"]
    C: Float[Array, "... p nx"]
    D: Float[Array, "... p m"]
    ts: float | None = eqx.field(static=True, default=None, kw_only=True)

    def __check_init__(self):
        a, b, c, d = (np.shape(x) for x in (self.A, self.B, self.C, self.D))
        if len(a) < 2 or a[-1] != a[-2]:
            raise ValueError(f"StateSpace: A must be square, got {a}")
        if (
            len(b) < 2
            or len(c) < 2
            or len(d) < 2
            or b[-2] != a[-1]
            or c[-1] != a[-1]
            or d[-2] != c[-2]
            or d[-1] != b[-1]
        ):
            raise ValueError(f"StateSpace: inconsistent shapes A{a} B{b} C{c} D{d}")
        if self.ts is not None and not self.ts > 0:
            raise ValueError(f"StateSpace: sampling period ts must be > 0 s, got {self.ts}")

    @property
    def n_states(self) -> int:
        return int(np.shape(self.A)[-1])

    @property
    def n_inputs(self) -> int:
        return int(np.shape(self.B)[-1])

    @property
    def n_outputs(self) -> int:
        return int(np.shape(self.C)[-2])

    @property
    def is_discrete(self) -> bool:
        return self.ts is not None

    @eqx.filter_jit
    def __call__(self, s: Complex[Array, " N"]) -> Complex[Array, "N p m"]:
        """Transfer matrix ``C (sI − A)⁻¹ B + D`` at complex ``s`` (``z`` for a discrete
        system), ``(N, p, m)`` (with A's batch dimensions in front)."""
        s = jnp.asarray(s, dtype=jnp.complex128).reshape(-1)
        eye = jnp.eye(self.n_states, dtype=jnp.complex128)
        sIA = s[:, None, None] * eye - self.A[..., None, :, :]
        rhs = jnp.broadcast_to(self.B[..., None, :, :], sIA.shape[:-1] + (self.n_inputs,))
        X = jnp.linalg.solve(sIA, rhs.astype(jnp.complex128))
        return self.C[..., None, :, :] @ X + self.D[..., None, :, :]

    freqresp = __call__

    @eqx.filter_jit
    def response(self, omega: Float[Array, " N"]) -> Complex[Array, "N p m"]:
        """Frequency response at ω (rad/s): ``H(jω)``, or ``H(e^{jω t_s})`` for a discrete
        system (meaningful up to π/t_s). ``(N, p, m)``."""
        omega = jnp.asarray(omega, dtype=jnp.float64)
        return self(jnp.exp(1j * omega * self.ts) if self.is_discrete else 1j * omega)

    at_omega = response

    def poles(self) -> Complex[Array, " nx"]:
        """Eigenvalues of ``A`` (rad/s for a continuous system, z for a discrete one)."""
        return jnp.linalg.eigvals(self.A)

    def n_unstable_poles(self, tol: float = 0.0) -> Int[Array, ""]:
        """Poles with ``Re s > tol`` (continuous) or ``|z| > 1 + tol`` (discrete)."""
        p = self.poles()
        bad = (jnp.abs(p) > 1.0 + tol) if self.is_discrete else (jnp.real(p) > tol)
        return jnp.sum(bad, axis=-1)

    def is_stable(self, tol: float = 0.0) -> Bool[Array, ""]:
        """Every pole has ``Re s < −tol`` (continuous) or ``|z| < 1 − tol`` (discrete)."""
        p = self.poles()
        ok = (jnp.abs(p) < 1.0 - tol) if self.is_discrete else (jnp.real(p) < -tol)
        return jnp.all(ok, axis=-1)

    # ---- discrete-time simulation -----------------------------------------------------
    def initial_state(self) -> Float[Array, " nx"]:
        return jnp.zeros(self.n_states)

    def step(self, x: Float[Array, " nx"], u: Float[Array, " m"]):
        """One sample of a discrete system: ``(x_next, y)`` (the body of a ``lax.scan``)."""
        return self.A @ x + self.B @ u, self.C @ x + self.D @ u


# ---- interconnections ------------------------------------------------------------------
def _same_ts(a: StateSpace, b: StateSpace) -> float | None:
    if a.ts != b.ts:
        raise ValueError(f"cannot connect systems with sampling periods {a.ts} and {b.ts}")
    return a.ts


def series(first: StateSpace, second: StateSpace) -> StateSpace:
    """The cascade ``second ∘ first`` (``u → first → second → y``), i.e. ``H₂ H₁``.

    State ordering ``[x₁; x₂]``.
    """
    ts = _same_ts(first, second)
    A1, B1, C1, D1 = first.A, first.B, first.C, first.D
    A2, B2, C2, D2 = second.A, second.B, second.C, second.D
    n1, n2 = A1.shape[-1], A2.shape[-1]
    A = jnp.block([[A1, jnp.zeros((n1, n2))], [B2 @ C1, A2]])
    B = jnp.concatenate([B1, B2 @ D1], axis=0)
    C = jnp.concatenate([D2 @ C1, C2], axis=1)
    return StateSpace(A, B, C, D2 @ D1, ts=ts)


def block_diag(sys: StateSpace, n: int) -> StateSpace:
    """``n`` decoupled copies of ``sys`` (``I_n ⊗ sys``; states, inputs, outputs interleaved
    per copy)."""
    eye = jnp.eye(n)
    k = [jnp.kron(eye, M) for M in (sys.A, sys.B, sys.C, sys.D)]
    return StateSpace(*k, ts=sys.ts)


@eqx.filter_jit
def feedback(plant: StateSpace, controller: StateSpace) -> StateSpace:
    """Negative-feedback loop ``u = G (r − y)``, ``y = P u``: input ``r``, outputs ``[y; u]``,
    state ``[x_P; x_G]``.

    ``plant`` P maps ``m`` inputs to ``p`` outputs; ``controller`` G maps ``p`` to ``m``. With
    feedthroughs, ``u = F (C_G x_G − D_G C_P x_P + D_G r)``, ``F = (I + D_G D_P)⁻¹``; the loop
    is ill-posed when ``I + D_G D_P`` is singular (check :func:`closed_loop_well_posed`).
    """
    ts = _same_ts(plant, controller)
    Ap, Bp, Cp, Dp = plant.A, plant.B, plant.C, plant.D
    Ag, Bg, Cg, Dg = controller.A, controller.B, controller.C, controller.D
    m, p = Bp.shape[-1], Cp.shape[-2]
    nx, nc = Ap.shape[-1], Ag.shape[-1]
    F = jnp.linalg.inv(jnp.eye(m) + Dg @ Dp)
    Ku = jnp.concatenate([-F @ Dg @ Cp, F @ Cg], axis=1)  # u = Ku x + Kr r
    Kr = F @ Dg
    Cy = jnp.concatenate([Cp, jnp.zeros((p, nc))], axis=1) + Dp @ Ku
    Dy = Dp @ Kr
    A = jnp.block([[Ap, jnp.zeros((nx, nc))], [jnp.zeros((nc, nx)), Ag]])
    A = A + jnp.concatenate([Bp @ Ku, -Bg @ Cy], axis=0)
    B = jnp.concatenate([Bp @ Kr, Bg @ (jnp.eye(p) - Dy)], axis=0)
    return StateSpace(
        A, B, jnp.concatenate([Cy, Ku], axis=0), jnp.concatenate([Dy, Kr], axis=0), ts=ts
    )


def closed_loop_matrix(plant: StateSpace, controller: StateSpace) -> Float[Array, "nc nc"]:
    """State matrix of :func:`feedback` ``(plant, controller)`` (state ``[x_P; x_G]``)."""
    return feedback(plant, controller).A


def closed_loop_well_posed(plant: StateSpace, controller: StateSpace, rtol: float = 1e-10):
    """``True`` when ``I + D_G D_P`` is numerically invertible (the loop is well posed)."""
    m = plant.B.shape[-1]
    sv = jnp.linalg.svd(jnp.eye(m) + controller.D @ plant.D, compute_uv=False)
    return sv[-1] > rtol * sv[0]


def closed_loop_poles(plant: StateSpace, controller: StateSpace) -> Complex[Array, " nc"]:
    """Closed-loop poles: eigenvalues of :func:`closed_loop_matrix` (rad/s or z)."""
    return jnp.linalg.eigvals(closed_loop_matrix(plant, controller))


def closed_loop_is_stable(
    plant: StateSpace, controller: StateSpace, tol: float = 0.0
) -> Bool[Array, ""]:
    """Closed loop well posed and every pole stable (``Re s < −tol``, or ``|z| < 1 − tol``)."""
    cl = feedback(plant, controller)
    return cl.is_stable(tol) & closed_loop_well_posed(plant, controller)


# ---- discretization ----------------------------------------------------------------------
def _continuous(sys: StateSpace, what: str) -> None:
    if sys.is_discrete:
        raise ValueError(f"{what}: the system is already discrete (ts = {sys.ts} s)")


@eqx.filter_jit
def zoh(sys: StateSpace, ts: float) -> StateSpace:
    """Exact zero-order-hold discretization of a continuous ``sys`` with period ``ts`` (s)."""
    _continuous(sys, "zoh")
    nx, m = sys.B.shape[-2:]
    M = jnp.zeros((nx + m, nx + m)).at[:nx, :nx].set(sys.A).at[:nx, nx:].set(sys.B)
    E = jsl.expm(M * ts)
    return StateSpace(E[:nx, :nx], E[:nx, nx:], sys.C, sys.D, ts=float(ts))


@eqx.filter_jit
def tustin(sys: StateSpace, ts: float, prewarp: float | None = None) -> StateSpace:
    """Bilinear (Tustin) discretization with period ``ts`` (s); with ``prewarp`` (rad/s) the
    response is exact at that frequency. Same realization as ``scipy.signal.cont2discrete``
    with ``method="bilinear"``."""
    _continuous(sys, "tustin")
    A, B, C, D = sys.A, sys.B, sys.C, sys.D
    nx = A.shape[-1]
    h = ts if prewarp is None else 2.0 * np.tan(prewarp * ts / 2.0) / prewarp
    eye = jnp.eye(nx)
    ima = eye - 0.5 * h * A
    Ad = jnp.linalg.solve(ima, eye + 0.5 * h * A)
    Bd = jnp.linalg.solve(ima, h * B)
    Cd = jnp.linalg.solve(ima.T, C.T).T
    Dd = D + 0.5 * C @ Bd
    return StateSpace(Ad, Bd, Cd, Dd, ts=float(ts))


def _cosh_sqrt(u):
    """``cosh(√u)`` for real u of either sign, smooth at 0 (entire function of u)."""
    small = jnp.abs(u) < 1e-4
    us = jnp.where(small, 1.0, u)
    pos = jnp.cosh(jnp.sqrt(jnp.where(us > 0, us, 1.0)))
    neg = jnp.cos(jnp.sqrt(jnp.where(us < 0, -us, 1.0)))
    series_ = 1.0 + u / 2.0 + u * u / 24.0
    return jnp.where(small, series_, jnp.where(u > 0, pos, neg))


def _pair(zeta, w, ts):
    """``q² + c1 q + c2`` with roots ``e^{r t_s}``, ``r = −ζω ± ω√(ζ²−1)`` (real, smooth in ζ)."""
    c1 = -2.0 * jnp.exp(-zeta * w * ts) * _cosh_sqrt((w * ts) ** 2 * (zeta**2 - 1.0))
    c2 = jnp.exp(-2.0 * zeta * w * ts)
    return c1, c2


def _matched_sections(g, ts: float, infinite_zeros: str):
    """Matched pole-zero coefficients of g's sections (the one implementation).

    Returns ``(lag, notch, lowpass)``: ``lag = (K, a, b)`` for ``K (q − a)/(q − b)``;
    ``notch = (K, n1, n2, d1, d2)`` for ``K (q² + n1 q + n2)/(q² + d1 q + d2)``;
    ``lowpass = (K, a, b)`` for ``K (q − a)/(q − b)`` with ``a = −1`` (zero at z = −1) or
    ``a = 0`` (the zero at ∞ kept: a one-sample delay ``K/(q − b)``, flagged by ``a = 0``).
    Every section has unit DC gain except through ``g.k``.
    """
    if infinite_zeros not in INFINITE_ZEROS:
        raise ValueError(f"infinite_zeros must be one of {INFINITE_ZEROS}, got {infinite_zeros!r}")
    z, p = g.lag_zeros, g.lag_poles
    a, b = jnp.exp(-z * ts), jnp.exp(-p * ts)
    lag = ((z / p) * (1.0 - b) / (1.0 - a), a, b)
    n1, n2 = _pair(g.notch_zeta_num, g.notch_omega, ts)
    d1, d2 = _pair(g.notch_zeta_den, g.notch_omega, ts)
    notch = ((1.0 + d1 + d2) / (1.0 + n1 + n2), n1, n2, d1, d2)
    bl = jnp.exp(-g.lowpass * ts)
    idx = np.arange(np.size(g.lowpass))
    if infinite_zeros == "minus_one":
        to_minus_one = np.ones(idx.size, dtype=bool)
    elif infinite_zeros == "all_but_one":
        to_minus_one = idx > 0
    else:
        to_minus_one = np.zeros(idx.size, dtype=bool)
    lowpass = (
        jnp.where(to_minus_one, (1.0 - bl) / 2.0, 1.0 - bl),
        jnp.where(to_minus_one, -1.0, 0.0),
        bl,
    )
    return lag, notch, lowpass, to_minus_one


@eqx.filter_jit
def matched(g, ts: float, infinite_zeros: str = "minus_one") -> StateSpace:
    """Matched pole-zero discretization of the scalar compensator ``g`` (a
    :class:`hapid.control.Compensator`; period ``ts`` in s), DC gain matched.

    ``infinite_zeros``: ``"minus_one"`` (default; every zero at s = ∞ maps to z = −1),
    ``"all_but_one"`` (a strictly proper g_d: one sample of computation delay) or ``"delay"``
    (none: python-control's ``sample_system(method="matched")``). Requires no pole or zero
    of g at s = 0. Differentiable in g's parameters. SISO discrete :class:`StateSpace`.
    """
    (Kl, al, bl), (Kn, n1, n2, d1, d2), (Kp, ap, bp), to_m1 = _matched_sections(
        g, ts, infinite_zeros
    )
    one = jnp.ones((1, 1))
    sys = StateSpace(
        jnp.zeros((0, 0)), jnp.zeros((0, 1)), jnp.zeros((1, 0)), g.k * one, ts=float(ts)
    )
    for j in range(np.size(g.lag_zeros)):  # K (q − a)/(q − b) = K + K (b − a)/(q − b)
        sec = StateSpace(
            bl[j] * one, one, (Kl[j] * (bl[j] - al[j])) * one, Kl[j] * one, ts=float(ts)
        )
        sys = series(sys, sec)
    for i in range(np.size(g.notch_omega)):  # controllable companion form
        A = jnp.stack([jnp.stack([0.0 * d1[i], 1.0 + 0.0 * d1[i]]), jnp.stack([-d2[i], -d1[i]])])
        C = (Kn[i] * jnp.stack([n2[i] - d2[i], n1[i] - d1[i]])).reshape(1, 2)
        sys = series(sys, StateSpace(A, jnp.array([[0.0], [1.0]]), C, Kn[i] * one, ts=float(ts)))
    for j in range(np.size(g.lowpass)):
        if to_m1[j]:
            sec = StateSpace(
                bp[j] * one, one, (Kp[j] * (bp[j] - ap[j])) * one, Kp[j] * one, ts=float(ts)
            )
        else:
            sec = StateSpace(bp[j] * one, one, Kp[j] * one, jnp.zeros((1, 1)), ts=float(ts))
        sys = series(sys, sec)
    return sys


@eqx.filter_jit
def matched_response(
    g, omega: Float[Array, " N"], ts: float, infinite_zeros: str = "minus_one"
) -> Complex[Array, " N"]:
    """``g_d(e^{jω t_s})`` of :func:`matched` in closed form (ω in rad/s), ``(N,)``."""
    (Kl, al, bl), (Kn, n1, n2, d1, d2), (Kp, ap, bp), to_m1 = _matched_sections(
        g, ts, infinite_zeros
    )
    q = jnp.exp(1j * jnp.asarray(omega, dtype=jnp.float64) * ts)[:, None]
    lag = jnp.prod(Kl * (q - al) / (q - bl), axis=-1)
    notch = jnp.prod(Kn * (q * q + n1 * q + n2) / (q * q + d1 * q + d2), axis=-1)
    lp = jnp.prod(Kp * jnp.where(to_m1, q - ap, 1.0) / (q - bp), axis=-1)
    return g.k * lag * notch * lp
