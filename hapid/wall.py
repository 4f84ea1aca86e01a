# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Rendering a virtual wall through the sampled force loop (the haptic use of the controller).

The force controller makes the sensed rod force ``R_I`` follow a desired ``R_D``; a haptic
scene sets ``R_D`` from the measured position. Here the scene is a unilateral wall with
normal ``e`` (a unit Cartesian direction of the stylus coordinates ``ξ``) and stiffness
``k_w`` (N/m, or N·m/rad for a rotational direction):

    ξ̂ = J⁻¹ L                                  stylus estimate from the encoders (rigid chain)
    F_d = −k_w · max(eᵀ ξ̂ − x_wall, 0) · e     the wall's Cartesian force on the stylus
    R_D = −J⁻ᵀ F_d                              the same force in rod space (sensor convention)

while the user's arm pushes the hand mass with ``f_user(t) · e`` (a ramp to ``push`` N plus an
optional slow wobble), an input the device has with ``state_space(user=True)``.

Two references separate the two sources of rendering error:

- :func:`ideal_wall` — the designer's wall: a perfect force source and a perfect position
  estimate on the stylus, with the hand's static stiffness (closed form, linear solve).
- :func:`perfect_control_wall` — the same device statics with perfect force tracking
  (``R_I = R_D`` exactly) but the real position estimate from motor-side encoders, which
  include the chain's compliance (traction and sensor springs): what the best force
  controller could render on this device.

The closed-loop steady state (exact linear solve of the sampled loop with the wall in contact)
and the time-domain run (:func:`render_wall`, ``lax.scan``, friction optional) then show what
the MIMO and SISO controllers add: steady-state error from ``T(0) ≠ I`` and, during motion,
*directional distortion* — Cartesian force off the wall normal (the non-isotropic plant leaks
force into other directions unless the controller inverts it).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from . import _config  # noqa: F401
from ._plain import jsonable
from .closed_loop import closed_loop
from .device import ParallelDevice
from .lti import zoh


class WallUnstableWarning(UserWarning):
    """The contact loop (force loop + wall) is unstable at the requested stiffness."""


def translational(device: ParallelDevice) -> np.ndarray:
    """``(n,)`` bool: which stylus coordinates are translations (m) rather than rotations."""
    return np.abs(np.asarray(device.geometry.dof)[:3]).sum(axis=0) > 0


class EquilibriumStatus(enum.StrEnum):
    """Outcome of :func:`perfect_control_wall` (:class:`PerfectControlWall`); ``ok`` means
    ``OK`` (a finite equilibrium)."""

    OK = "ok"
    NON_FINITE = "non-finite"


@dataclasses.dataclass(frozen=True)
class PerfectControlWall:
    """Result of :func:`perfect_control_wall`: the static equilibrium under perfect force
    tracking. ``penetration``: the true stylus penetration along ``e``; ``estimate``: the
    encoder-based estimate ``eᵀ ξ̂`` of it (both m along a translation, rad along a
    rotation)."""

    penetration: float
    estimate: float

    @property
    def status(self) -> EquilibriumStatus:
        finite = np.isfinite(self.penetration) and np.isfinite(self.estimate)
        return EquilibriumStatus.OK if finite else EquilibriumStatus.NON_FINITE

    @property
    def ok(self) -> bool:
        return self.status is EquilibriumStatus.OK

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``penetration``, ``estimate``."""
        return jsonable({"status": self.status, "ok": self.ok, "penetration": self.penetration,
                         "estimate": self.estimate})  # fmt: skip


class ContactStatus(enum.StrEnum):
    """Stability of the contact loop (force loop with the wall closed) of
    :class:`WallSteadyState`; ``ok`` means ``STABLE`` (spectral radius ``< 1``)."""

    STABLE = "stable"
    UNSTABLE = "unstable"


@dataclasses.dataclass(frozen=True)
class WallSteadyState:
    """Result of :func:`closed_loop_wall_steady_state`: the steady state of the sampled
    loop with the wall in contact under a constant push.

    ``penetration``: true stylus penetration along ``e``; ``estimate``: its encoder-based
    estimate ``eᵀ ξ̂`` (m along a translation, rad along a rotation); ``spectral_radius``:
    of the sampled loop with the wall closed (``< 1``: the contact is stable; otherwise the
    steady state is not reached); ``R_I``, ``R_D``: ``(n,)`` sensed and desired rod forces
    (N)."""

    penetration: float
    estimate: float
    spectral_radius: float
    R_I: np.ndarray
    R_D: np.ndarray

    @property
    def status(self) -> ContactStatus:
        return _contact(self.spectral_radius)

    @property
    def ok(self) -> bool:
        return self.status is ContactStatus.STABLE

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``penetration``, ``estimate``,
        ``spectral_radius``, ``R_I``, ``R_D`` (lists)."""
        return jsonable({"status": self.status, "ok": self.ok, "penetration": self.penetration,
                         "estimate": self.estimate, "spectral_radius": self.spectral_radius,
                         "R_I": self.R_I, "R_D": self.R_D})  # fmt: skip


@dataclasses.dataclass(frozen=True)
class WallRun:
    """Result of :func:`render_wall`: ``T`` samples of the sampled loop rendering the wall.

    ``t`` ``(T,)`` s; ``xi``, ``xi_hat`` ``(T, n)``: true stylus coordinates and their
    encoder estimate (m, rad); ``R_I``, ``R_D`` ``(T, n)``: sensed and desired rod forces
    (N); ``F`` ``(T, n)``: Cartesian force of the device on the stylus, ``−Jᵀ R_I``; ``F_d``
    ``(T, n)``: the wall's commanded Cartesian force; ``f_user`` ``(T,)``: the arm's force
    (N); ``e`` ``(n,)``: the unit wall normal; ``translational`` ``(n,)`` bool (see
    :func:`translational`); ``contact_spectral_radius``: of the linear loop with the wall
    closed (``status``: ``STABLE`` when ``< 1``)."""

    t: np.ndarray
    xi: np.ndarray
    xi_hat: np.ndarray
    R_I: np.ndarray
    R_D: np.ndarray
    F: np.ndarray
    F_d: np.ndarray
    f_user: np.ndarray
    e: np.ndarray
    translational: np.ndarray
    contact_spectral_radius: float

    @property
    def status(self) -> ContactStatus:
        return _contact(self.contact_spectral_radius)

    @property
    def ok(self) -> bool:
        return self.status is ContactStatus.STABLE

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``n_samples``, ``contact_spectral_radius``
        (not the arrays)."""
        return jsonable({"status": self.status, "ok": self.ok, "n_samples": len(self.t),
                         "contact_spectral_radius": self.contact_spectral_radius})  # fmt: skip


@dataclasses.dataclass(frozen=True)
class WallMetrics:
    """Result of :func:`wall_metrics`: what a :class:`WallRun` rendered (see there for the
    definitions); ``status`` is the run's contact :class:`ContactStatus`."""

    penetration: float
    estimate: float
    off_axis_force: float
    off_axis_motion: float
    force_error: float
    contact_spectral_radius: float

    @property
    def status(self) -> ContactStatus:
        return _contact(self.contact_spectral_radius)

    @property
    def ok(self) -> bool:
        return self.status is ContactStatus.STABLE

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, then every field."""
        return jsonable({"status": self.status, "ok": self.ok} | dataclasses.asdict(self))


def _contact(spectral_radius) -> ContactStatus:
    return ContactStatus.STABLE if spectral_radius < 1.0 else ContactStatus.UNSTABLE


def _unit(direction, n: int) -> np.ndarray:
    e = np.asarray(direction, dtype=float).reshape(-1)
    if e.shape != (n,):
        raise ValueError(
            f"wall direction must have n = {n} Cartesian components, got shape {e.shape}"
        )
    if not np.all(np.isfinite(e)) or np.linalg.norm(e) == 0:
        raise ValueError("wall direction must be a finite, non-zero vector")
    return e / np.linalg.norm(e)


def _wall_matrix(device: ParallelDevice, e, k_wall) -> Array:
    """``W`` with ``R_D = W L`` while in contact: ``W = k_w J⁻ᵀ e eᵀ J⁻¹``."""
    Jinv = jnp.linalg.inv(device.jacobian())
    return k_wall * Jinv.T @ jnp.outer(e, e) @ Jinv


def ideal_wall(device: ParallelDevice, direction, k_wall: float, push: float) -> float:
    """Penetration (m or rad along ``e``) of the designer's wall: the stylus held by a perfect
    wall ``F = −k_w (eᵀξ) e`` and the hand's static stiffness, the arm pushing ``push · e`` on
    the hand mass. Solves ``[[K1 + k_w eeᵀ, −K1], [−K1, K1 + K2]] [ξ; h] = [0; push e]``."""
    n = device.n
    e = _unit(direction, n)
    K1, K2 = np.diag(np.asarray(device.hand.k1)), np.diag(np.asarray(device.hand.k2))
    A = np.block([[K1 + k_wall * np.outer(e, e), -K1], [-K1, K1 + K2]])
    sol = np.linalg.solve(A, np.concatenate([np.zeros(n), push * e]))
    return float(e @ sol[:n])


def _stylus_rows(device: ParallelDevice, nx: int) -> np.ndarray:
    """Selector of the stylus coordinates ``ξ`` (positions ``2n:3n`` of ``q``) in the state."""
    n = device.n
    S = np.zeros((n, nx))
    S[:, 2 * n : 3 * n] = np.eye(n)
    return S


def perfect_control_wall(device: ParallelDevice, direction, k_wall: float,
                         push: float) -> PerfectControlWall:  # fmt: skip
    """Static equilibrium of the device with perfect force tracking (``R_I = R_D(L)``) and the
    real encoder-based position estimate. Solves ``A x + B_R R_A + B_u f = 0``,
    ``C_R x = W C_L x`` for the state ``x`` and the actuator force ``R_A``.

    ``direction``: the wall normal ``e``, ``(n,)`` (normalized here); ``k_wall``: wall
    stiffness (N/m along a translation); ``push``: the arm's force on the hand along ``e``
    (N). Returns a :class:`PerfectControlWall`; ``ValueError`` for a bad ``direction``."""
    n = device.n
    e = _unit(direction, n)
    ss = device.state_space(user=True)
    A, B, C = (np.asarray(x) for x in (ss.A, ss.B, ss.C))
    nx = A.shape[0]
    W = np.asarray(_wall_matrix(device, jnp.asarray(e), k_wall))
    CL, CR = C[:n], C[n:]
    lhs = np.block([[A, B[:, :n]], [CR - W @ CL, np.zeros((n, n))]])
    rhs = np.concatenate([-B[:, n : 2 * n] @ (push * e), np.zeros(n)])
    sol = np.linalg.solve(lhs, rhs)
    x = sol[:nx]
    xi = _stylus_rows(device, nx) @ x
    xi_hat = np.linalg.solve(np.asarray(device.jacobian()), CL @ x)
    return PerfectControlWall(float(e @ xi), float(e @ xi_hat))


def _discrete_with_user(device: ParallelDevice, substeps: int, friction: bool):
    return zoh(device.state_space(friction=friction, user=True), device.ts / substeps)


def closed_loop_wall_steady_state(device: ParallelDevice, controller, direction, k_wall: float,
                                  push: float) -> WallSteadyState:  # fmt: skip
    """Exact steady state of the sampled loop (device + delay + discrete ``controller``) with
    the wall in contact (linear), for a constant ``push`` (N) along the wall normal
    ``direction`` (``(n,)``, normalized here) against a wall of stiffness ``k_wall`` (N/m).
    Returns a :class:`WallSteadyState` (with the spectral radius of the loop with the wall
    closed: ``< 1``, the contact is stable); ``ValueError`` for a bad ``direction``."""
    n = device.n
    e = _unit(direction, n)
    cl = closed_loop(device, controller)
    A, B, C = (np.asarray(x) for x in (cl.A, cl.B, cl.C))
    nxd = device.discrete().A.shape[0]
    Bu = np.zeros((A.shape[0], n))
    Bu[:nxd] = np.asarray(_discrete_with_user(device, 1, False).B)[:, n : 2 * n]
    W = np.asarray(_wall_matrix(device, jnp.asarray(e), k_wall))
    Aw = A + B @ W @ C[:n]  # R_D = W L, L = C[:n] x (no feedthrough from R_D)
    x = np.linalg.solve(np.eye(A.shape[0]) - Aw, Bu @ (push * e))
    xi = _stylus_rows(device, nxd) @ x[:nxd]
    y = C @ x
    xi_hat = np.linalg.solve(np.asarray(device.jacobian()), y[:n])
    rho = float(np.max(np.abs(np.linalg.eigvals(Aw))))
    return WallSteadyState(float(e @ xi), float(e @ xi_hat), rho, y[n:], W @ y[:n])


def max_wall_stiffness(device: ParallelDevice, controller, direction, *, k_max: float = 1e6,
                       k_min: float = 1e-2, n_scan: int = 60, rtol: float = 1e-3) -> float:  # fmt: skip
    """Largest ``k_w`` below which *every* wall stiffness gives a stable contact loop
    (spectral radius of the linear sampled loop with the wall closed ``< 1``).

    Stability need not be monotone in ``k_w`` (a loop can lose and regain stability), so a
    log-spaced scan of ``n_scan`` stiffnesses from ``k_min`` to ``k_max`` finds the first
    unstable one and bisection (in ``log k_w``, to ``rtol``) refines the boundary below it.
    Returns 0 if the loop is unstable already at ``k_min`` (the force loop itself is) and
    ``k_max`` if no scanned stiffness is unstable. A stability limit, not a recommendation:
    near it the contact rings."""

    def stable(k):
        return closed_loop_wall_steady_state(device, controller, direction, k, 1.0).ok

    ks = np.geomspace(k_min, k_max, n_scan)
    if not stable(ks[0]):
        return 0.0
    lo = hi = None
    for k_prev, k in zip(ks[:-1], ks[1:], strict=True):
        if not stable(k):
            lo, hi = k_prev, k
            break
    if lo is None:
        return float(k_max)
    while hi / lo > 1.0 + rtol:
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return float(lo)


def user_push(T: int, ts: float, push: float, *, ramp_s: float = 1.0, wobble: float = 0.0,
              wobble_hz: float = 1.5) -> np.ndarray:  # fmt: skip
    """Arm force profile (N), ``(T,)``: a smooth ramp to ``push`` over ``ramp_s`` seconds plus
    a wobble ``wobble · push · sin(2π f t)`` that starts with the ramp (a probing hand)."""
    t = np.arange(T) * ts
    r = np.clip(t / ramp_s, 0.0, 1.0)
    ramp = r * r * (3 - 2 * r)  # smoothstep
    return push * ramp * (1.0 + wobble * np.sin(2 * np.pi * wobble_hz * t))


def render_wall(device: ParallelDevice, controller, direction, *, k_wall: float = 1000.0,
                push: float = 2.0, x_wall: float = 0.0, duration: float = 6.0,
                ramp_s: float = 1.0, wobble: float = 0.0, wobble_hz: float = 1.5,
                friction: bool = False, substeps: int | None = None) -> WallRun:  # fmt: skip
    """Run the sampled force loop rendering a unilateral wall (see the module docstring).

    Args:
        device: a :class:`~hapid.device.ParallelDevice` (it has the hand the user pushes).
        controller: discrete controller (``A, B, C, D``, input error ``R_D − R_I``, output
            ``R_A``) at the device's sampling period, e.g. from ``discretize_controller``.
        direction: wall normal ``e`` in stylus coordinates, ``(n,)`` (normalized here).
        k_wall: wall stiffness (N/m along a translation).
        push: the arm's steady force on the hand along ``e`` (N); ``wobble`` adds a relative
            sinusoid at ``wobble_hz`` (a probing hand) that exercises the dynamic tracking.
        x_wall: wall position along ``e`` (m); 0 means in contact from the start.

    Returns a :class:`WallRun` of ``T = round(duration · fs)`` samples. Raises ``TypeError``
    for a device without a hand, ``ValueError`` for a device without actuator delay, a bad
    ``direction`` or a negative or non-finite ``k_wall``, ``push`` or ``duration``; warns
    :class:`WallUnstableWarning` when the contact loop is unstable.
    """
    if not isinstance(device, ParallelDevice):
        raise TypeError("render_wall needs a ParallelDevice (a device with a hand to push)")
    n, d = device.n, device.delay_samples
    if d < 1:
        raise ValueError("render_wall needs a device with at least one sample of actuator delay")
    for name, v in (("k_wall", k_wall), ("push", push), ("duration", duration)):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be finite and ≥ 0, got {v}")
    e = _unit(direction, n)
    rho = closed_loop_wall_steady_state(device, controller, e, k_wall, 1.0).spectral_radius
    if rho >= 1.0:
        warnings.warn(f"the contact loop with k_wall = {k_wall:g} is unstable (spectral radius "
                      f"{rho:.6f} ≥ 1): the rendered wall will not hold; lower k_wall (see "
                      "max_wall_stiffness)", WallUnstableWarning, stacklevel=2)  # fmt: skip
    m = substeps if substeps is not None else (10 if friction else 1)
    T = int(round(duration * device.fs_hz))
    f = user_push(T, device.ts, push, ramp_s=ramp_s, wobble=wobble, wobble_hz=wobble_hz)
    dev = _discrete_with_user(device, m, friction)
    J = device.jacobian()
    out = _simulate_wall(device, dev, controller, J, jnp.asarray(e), float(k_wall), float(x_wall),
                         jnp.asarray(f), m, friction, d)  # fmt: skip
    out = {k: np.asarray(v) for k, v in out.items()}
    return WallRun(t=np.arange(T) * device.ts, F=-out["R_I"] @ np.asarray(J), f_user=f, e=e,
                   translational=translational(device), contact_spectral_radius=rho, **out)  # fmt: skip


@functools.partial(jax.jit, static_argnums=(8, 9, 10))
def _simulate_wall(device, dev, ctrl, J, e, k_wall, x_wall, f_user, m, friction, d):
    n = device.n
    nx = dev.A.shape[0]
    Jinv = jnp.linalg.inv(J)
    B_ra, B_user = dev.B[:, :n], dev.B[:, -n:]
    B_fr = dev.B[:, n : 2 * n] if friction else None

    def step(carry, fu):
        x, buf, xc = carry
        u = buf[0]
        y = dev.C @ x + dev.D[:, :n] @ u
        L, R_I = y[:n], y[n:]
        xi_hat = Jinv @ L
        pen = jnp.maximum(e @ xi_hat - x_wall, 0.0)
        F_d = -k_wall * pen * e
        R_D = -Jinv.T @ F_d
        err = R_D - R_I
        u_cmd = ctrl.C @ xc + ctrl.D @ err
        xc = ctrl.A @ xc + ctrl.B @ err

        def sub(x, _):
            dx = dev.A @ x + B_ra @ u + B_user @ (fu * e)
            if friction:
                dx = dx + B_fr @ device.coulomb_force(x)
            return dx, None

        xi = x[2 * n : 3 * n]
        x, _ = jax.lax.scan(sub, x, None, length=m)
        buf = jnp.concatenate([buf[1:], u_cmd[None]], axis=0)
        return (x, buf, xc), {"xi": xi, "xi_hat": xi_hat, "R_I": R_I, "R_D": R_D, "F_d": F_d}

    init = (jnp.zeros(nx), jnp.zeros((d, n)), jnp.zeros(ctrl.A.shape[0]))
    _, out = jax.lax.scan(step, init, f_user)
    return out


def wall_metrics(sim: WallRun, *, settle_s: float = 1.5) -> WallMetrics:
    """What a :func:`render_wall` run rendered (:class:`WallMetrics`); ``settle_s`` (s):
    start of the window the ratios are taken over.

    - ``penetration`` — final true stylus penetration along ``e`` (mean of the last 0.5 s).
    - ``off_axis_force`` — RMS over the window ``t ≥ settle_s`` of the Cartesian force
      perpendicular to ``e`` (coordinates of the same kind as ``e``: translations with a
      translational wall), relative to the RMS force along ``e``: the directional distortion
      (0 for an isotropic rendering).
    - ``off_axis_motion`` — the same ratio for the stylus displacement: force leaking into
      the free directions moves the stylus sideways along the wall.
    - ``force_error`` — RMS of ``F − F_d`` over the window relative to RMS ``F_d``.
    """
    e, t = sim.e, sim.t
    w = t >= settle_s
    last = t >= t[-1] - 0.5
    tr = sim.translational
    kind = tr if np.all(e[~tr] == 0) else ~tr  # compare like with like (m with m, rad with rad)

    def ratio(X):
        along = X @ e
        perp = (X - along[:, None] * e)[:, kind]
        return float(
            np.sqrt(np.mean(np.sum(perp[w] ** 2, axis=1)))
            / max(np.sqrt(np.mean(along[w] ** 2)), 1e-300)
        )

    F, F_d = sim.F, sim.F_d
    ferr = float(
        np.sqrt(np.mean(np.sum((F - F_d)[w] ** 2, axis=1)))
        / max(np.sqrt(np.mean(np.sum(F_d[w] ** 2, axis=1))), 1e-300)
    )
    return WallMetrics(
        penetration=float(np.mean(sim.xi[last] @ e)),
        estimate=float(np.mean(sim.xi_hat[last] @ e)),
        off_axis_force=ratio(F),
        off_axis_motion=ratio(sim.xi),
        force_error=ferr,
        contact_spectral_radius=sim.contact_spectral_radius,
    )
