"""Simulated haptic interfaces as linear state-space models with measured outputs.

Every device maps the *applied* actuator forces ``R_A`` (``(n,)``, N, the paper's sign
convention: ``R_A = −Z_T L``) to the measured outputs ``y = [L; R_I]`` (``(2n,)``: encoder rod
lengths in m, force-sensor readings in N). The commanded force reaches the actuator after
``delay_samples`` sampling periods.

What the paper's procedure measures (section 4.1) is a pair of *transfer relations*, not the
physical parts: ``Z_H = −R_I L⁻¹`` and ``Z_T = −R_A L⁻¹`` with ``R_A`` the *commanded* forces
and ``L`` the encoder readings. These are properties of the device (independent of the
excitation) and are what ``impedances`` returns; ``P = Z_H Z_T⁻¹`` is then exactly the
command-to-sensor plant. ``sampled_impedances`` returns the same relations for the sampled
system (zero-order hold on the command, samples of the outputs), which is what a perfect
experiment on the simulated hardware recovers.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401
from ..defaults import FS_HZ
from ..impedance import ImpedanceModel, SecondOrder
from ..lti import StateSpace, zoh
from ._geometry import Geometry, Pose
from ._parts import ExtraModes, Hand, Mechanism


class Device(eqx.Module):
    """Base class: a linear plant from applied actuator force to ``[L; R_I]`` plus a delay."""

    fs_hz: float = eqx.field(static=True, default=FS_HZ, kw_only=True)
    delay_samples: int = eqx.field(static=True, default=1, kw_only=True)

    @property
    @abc.abstractmethod
    def n(self) -> int: ...

    @abc.abstractmethod
    def state_space(self, friction: bool = False, user: bool = False) -> StateSpace:
        """Continuous model, input: applied ``R_A`` (plus, with ``friction``, the Coulomb
        force on each motor as ``n`` extra inputs; then, with ``user``, a voluntary force the
        user's arm applies to the hand, ``n`` Cartesian inputs, where the device models a
        hand); outputs ``[L; R_I]``."""

    def coulomb_force(self, x: Float[Array, " nx"]) -> Float[Array, " n"]:
        """Smoothed Coulomb friction force on each motor (input to the friction channel)."""
        return jnp.zeros((self.n,))

    @property
    def ts(self) -> float:
        return 1.0 / self.fs_hz

    # ---- transfer relations -------------------------------------------------------------
    def transfer(self, s: Complex[Array, " N"]) -> tuple[Array, Array]:
        """``(H_L, H_R)``: ``(N, n, n)`` responses of ``L`` and ``R_I`` to the *applied* force."""
        H = self.state_space().freqresp(s)
        return H[:, : self.n, :], H[:, self.n :, :]

    def impedances(self, s: Complex[Array, " N"]) -> tuple[Array, Array]:
        """Continuous-time ``(Z_H(s), Z_T(s))``, each ``(N, n, n)`` (Z_T includes the delay)."""
        s = jnp.asarray(s, dtype=jnp.complex128)
        H_L, H_R = self.transfer(s)
        Z_H = -_right_solve(H_R, H_L)
        eye = jnp.broadcast_to(jnp.eye(self.n, dtype=jnp.complex128), H_L.shape)
        delay = jnp.exp(s * self.delay_samples * self.ts)[:, None, None]
        Z_T = -delay * _right_solve(eye, H_L)
        return Z_H, Z_T

    def Z_H(self, s):
        return self.impedances(s)[0]

    def Z_T(self, s):
        return self.impedances(s)[1]

    def Z_M(self, s):
        Z_H, Z_T = self.impedances(s)
        return Z_T - Z_H

    def P(self, s) -> Complex[Array, "N n n"]:
        """Command-to-sensor plant ``P(s) = Z_H Z_T⁻¹`` (with the actuator delay)."""
        s = jnp.asarray(s, dtype=jnp.complex128)
        _, H_R = self.transfer(s)
        return H_R * jnp.exp(-s * self.delay_samples * self.ts)[:, None, None]

    def discrete(self, substeps: int = 1, friction: bool = False) -> StateSpace:
        """ZOH discretization at ``ts / substeps`` (the delay is applied by the caller)."""
        return zoh(self.state_space(friction), self.ts / substeps)

    def sampled_impedances(self, omega: Float[Array, " N"]) -> tuple[Array, Array]:
        """``(Z_H, Z_T)`` of the sampled system at ``z = e^{jω t_s}`` (ZOH on the command)."""
        z = jnp.exp(1j * jnp.asarray(omega) * self.ts)
        H = self.discrete().freqresp(z)
        H_L, H_R = H[:, : self.n, :], H[:, self.n :, :]
        Z_H = -_right_solve(H_R, H_L)
        eye = jnp.broadcast_to(jnp.eye(self.n, dtype=jnp.complex128), H_L.shape)
        Z_T = -(z**self.delay_samples)[:, None, None] * _right_solve(eye, H_L)
        return Z_H, Z_T

    def sampled_P(self, omega: Float[Array, " N"]) -> Complex[Array, "N n n"]:
        z = jnp.exp(1j * jnp.asarray(omega) * self.ts)
        H = self.discrete().freqresp(z)
        return H[:, self.n :, :] * (z ** (-self.delay_samples))[:, None, None]


def _right_solve(A, B):
    """``A B⁻¹`` per frequency (``(N, n, n)``)."""
    return jnp.swapaxes(jnp.linalg.solve(jnp.swapaxes(B, -1, -2), jnp.swapaxes(A, -1, -2)), -1, -2)


class ParallelDevice(Device):
    """An ``n``-rod parallel interface: geometry + pose, hand + stylus, per-rod mechanism
    chain and extra modes (docs/device.md). The encoders sit on the motor/roller, so ``L`` is the
    motor-side rod displacement and the measured ``Z_H`` includes the chain's compliance.

    Generalized coordinates ``q = [u1, u2, ξ, h, r]``: motor and rod displacements along
    each rod (``n`` each, positive lengthening), stylus Cartesian coordinates ``ξ`` (``n``),
    hand masses ``h`` (``n``), extra-mode masses ``r`` (``n·m``).
    """

    geometry: Geometry
    pose: Pose
    hand: Hand
    mechanism: Mechanism
    modes: ExtraModes
    encoder: str = eqx.field(static=True, default="motor", kw_only=True)

    def __check_init__(self):
        if self.encoder not in ("motor", "rod"):
            raise ValueError(f"encoder must be 'motor' or 'rod', got {self.encoder!r}")

    @property
    def n(self) -> int:
        return self.geometry.n

    def jacobian(self) -> Float[Array, "n n"]:
        return self.geometry.jacobian(self.pose)

    def hand_rod_impedance(self, s) -> Complex[Array, "N n n"]:
        """Stylus + hand seen at the rod tips: ``J⁻ᵀ Z_cart(s) J⁻¹`` (``(N, n, n)``)."""
        Jinv = jnp.linalg.inv(self.jacobian())
        return Jinv.T @ self.hand.impedance(s) @ Jinv

    def _matrices(self, friction: bool):
        n, m = self.n, self.modes.count
        nq = 4 * n + n * m
        J = self.jacobian()
        I, Z = jnp.eye(n), jnp.zeros((n, n))
        mech, hand = self.mechanism, self.hand

        def blocks(*bl):
            return jnp.concatenate(list(bl) + [jnp.zeros((n, n * m))], axis=1)

        springs = [  # (relative-displacement map (n, nq), stiffness (n,), damping (n,))
            (blocks(I, Z, Z, Z), jnp.zeros(n), mech.b_viscous if friction else mech.b_drive),
            (blocks(I, -I, Z, Z), mech.k_t, mech.b_t),
            (blocks(Z, I, -J, Z), mech.k_s, mech.b_s),
            (blocks(Z, Z, I, -I), hand.k1, hand.b1),
            (blocks(Z, Z, Z, I), hand.k2, hand.b2),
        ]
        masses = [mech.m1, mech.m2, hand.m_s, hand.m_h]
        for j in range(m):
            w = 2 * np.pi * self.modes.f_hz[j]
            mr = self.modes.mass[j]
            D = jnp.zeros((n, nq)).at[:, self.modes.node[j] * n : self.modes.node[j] * n + n].set(I)
            D = D.at[:, 4 * n + j * n : 4 * n + (j + 1) * n].set(-I)
            springs.append(
                (D, jnp.full(n, mr * w**2), jnp.full(n, 2 * self.modes.zeta[j] * mr * w))
            )
            masses.append(jnp.full(n, mr))
        K = sum(D.T @ (k[:, None] * D) for D, k, _ in springs)
        C = sum(D.T @ (c[:, None] * D) for D, _, c in springs)
        Mdiag = jnp.concatenate(masses)
        return Mdiag, C, K, springs[2][0]

    def state_space(self, friction: bool = False, user: bool = False) -> StateSpace:
        n = self.n
        Mdiag, C, K, D_s = self._matrices(friction)
        nq = Mdiag.shape[0]
        Minv = 1.0 / Mdiag
        A = jnp.block(
            [[jnp.zeros((nq, nq)), jnp.eye(nq)], [-Minv[:, None] * K, -Minv[:, None] * C]]
        )
        # applied R_A is tension-positive: it pulls the motor back (−u1 direction)
        F = jnp.zeros((nq, n)).at[:n].set(-jnp.eye(n))
        inputs = [F]
        if friction:
            inputs.append(jnp.zeros((nq, n)).at[:n].set(jnp.eye(n)))
        if user:  # voluntary Cartesian force on the hand masses h (coordinates 3n:4n)
            inputs.append(jnp.zeros((nq, n)).at[3 * n : 4 * n].set(jnp.eye(n)))
        Bq = jnp.concatenate(inputs, axis=1)
        B = jnp.concatenate([jnp.zeros_like(Bq), Minv[:, None] * Bq], axis=0)
        off = 0 if self.encoder == "motor" else n
        L_row = jnp.zeros((n, 2 * nq)).at[:, off : off + n].set(jnp.eye(n))
        k_s, b_s = self.mechanism.k_s, self.mechanism.b_s
        R_row = -jnp.concatenate([k_s[:, None] * D_s, b_s[:, None] * D_s], axis=1)
        Cm = jnp.concatenate([L_row, R_row], axis=0)
        return StateSpace(A, B, Cm, jnp.zeros((2 * n, Bq.shape[1])))

    def coulomb_force(self, x):
        nq = x.shape[-1] // 2
        v1 = x[nq : nq + self.n]
        mech = self.mechanism
        return -mech.coulomb * jnp.tanh(v1 / mech.v_smooth)

    def rigid_model(self) -> ImpedanceModel:
        """The device's second-order parts: the hand's low-frequency expansion (Taylor to s²
        of ``J⁻ᵀ Z_cart J⁻¹`` at s = 0) and the rigid mechanism (``m1 + m2`` plus mode masses,
        linear-equivalent drive damping, no stiffness). Exact only for a rigid chain, no
        delay and a second-order hand; otherwise the reference a fit should approach at low
        frequency."""
        h = self.hand

        def zc(s):  # per-DOF Cartesian impedance at real s
            z1 = h.k1 + h.b1 * s
            z2 = h.k2 + h.b2 * s + h.m_h * s**2
            return h.m_s * s**2 + z1 * z2 / (z1 + z2)

        K = zc(0.0)
        Bc = jax.jacfwd(zc)(0.0)
        Mc = 0.5 * jax.jacfwd(jax.jacfwd(zc))(0.0)
        Jinv = jnp.linalg.inv(self.jacobian())
        to_rod = lambda d: Jinv.T @ jnp.diag(d) @ Jinv  # noqa: E731
        hand = SecondOrder(to_rod(Mc), to_rod(Bc), to_rod(K))
        mm = self.mechanism.m1 + self.mechanism.m2 + jnp.sum(self.modes.mass)
        mech = SecondOrder(
            jnp.diag(mm), jnp.diag(self.mechanism.b_drive), jnp.zeros((self.n, self.n))
        )
        return ImpedanceModel.from_hand_mechanism(hand, mech)


class SecondOrderDevice(Device):
    """A strictly second-order device: ``Z_H = M_H s² + B_H s + K_H`` and
    ``Z_M = M_M s² + B_M s + K_M`` exactly (rod space), ``L`` the common rod displacement.
    The reference truth for recovery tests; ``delay_samples`` defaults to 0 here."""

    hand: SecondOrder
    mechanism: SecondOrder
    delay_samples: int = eqx.field(static=True, default=0, kw_only=True)

    @property
    def n(self) -> int:
        return self.hand.n

    @property
    def model(self) -> ImpedanceModel:
        return ImpedanceModel.from_hand_mechanism(self.hand, self.mechanism)

    def state_space(self, friction: bool = False, user: bool = False) -> StateSpace:
        if user:
            raise ValueError("SecondOrderDevice has no hand dynamics to push on; a user force "
                             "input needs a ParallelDevice (its hand model has the arm)")  # fmt: skip
        n = self.n
        tot = self.hand + self.mechanism
        MTi = jnp.linalg.inv(tot.M)
        I, Z = jnp.eye(n), jnp.zeros((n, n))
        A = jnp.block([[Z, I], [-MTi @ tot.K, -MTi @ tot.B]])
        Bin = jnp.concatenate([Z, -MTi], axis=0)
        G = self.hand.M @ MTi
        C = jnp.block([[I, Z], [G @ tot.K - self.hand.K, G @ tot.B - self.hand.B]])
        D = jnp.concatenate([Z, G], axis=0)
        if friction:
            Bin = jnp.concatenate([Bin, jnp.zeros((2 * n, n))], axis=1)
            D = jnp.concatenate([D, jnp.zeros((2 * n, n))], axis=1)
        return StateSpace(A, Bin, C, D)
