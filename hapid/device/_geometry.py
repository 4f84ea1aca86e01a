"""Parallel-rod geometry: base pivots, stylus attachments, pose → rod Jacobian.

Coordinates: world frame in metres; the stylus frame has its x axis along the stylus and its
origin at the grip point ``c``. A device with ``n`` rods controls ``n`` Cartesian degrees of
freedom chosen by a ``(6, n)`` selection matrix ``dof`` of twists ``[v; ω]`` (translations in
the world frame, rotations about stylus-frame axes).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _config  # noqa: F401


def rotation(yaw, pitch, roll) -> Float[Array, "3 3"]:
    """Rotation matrix ``Rz(yaw) Ry(pitch) Rx(roll)`` (angles in rad)."""
    cy, sy = jnp.cos(yaw), jnp.sin(yaw)
    cp, sp = jnp.cos(pitch), jnp.sin(pitch)
    cr, sr = jnp.cos(roll), jnp.sin(roll)
    Rz = jnp.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = jnp.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rx = jnp.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return Rz @ Ry @ Rx


class Pose(eqx.Module):
    """Stylus pose: grip-point position ``center`` (m, world) and yaw/pitch/roll (rad)."""

    center: Float[Array, " 3"] = eqx.field(default_factory=lambda: jnp.array([0.0, 0.0, 0.60]))
    yaw: Float[Array, ""] = 0.0
    pitch: Float[Array, ""] = 0.0
    roll: Float[Array, ""] = 0.0

    @property
    def R(self) -> Float[Array, "3 3"]:
        return rotation(self.yaw, self.pitch, self.roll)

    def moved(self, dx=0.0, dy=0.0, dz=0.0, dyaw=0.0, dpitch=0.0, droll=0.0) -> Pose:
        """A new pose displaced by (dx, dy, dz) m and (dyaw, dpitch, droll) rad."""
        return Pose(
            center=jnp.asarray(self.center) + jnp.array([dx, dy, dz]),
            yaw=self.yaw + dyaw,
            pitch=self.pitch + dpitch,
            roll=self.roll + droll,
        )


class Geometry(eqx.Module):
    """Rod layout of an ``n``-rod parallel interface.

    base:   ``(n, 3)`` base pivot of each rod, world frame (m).
    attach: ``(n, 3)`` rod-tip attachment on the stylus, stylus frame, relative to the grip
            point (m).
    dof:    ``(6, n)`` the Cartesian degrees of freedom: column ``k`` is the twist
            ``[v; ω]`` (v world frame, ω stylus frame) of generalized coordinate ``k``.
    """

    base: Float[Array, "n 3"]
    attach: Float[Array, "n 3"]
    dof: Float[Array, "6 n"]

    def __check_init__(self):
        n = np.shape(self.base)[0]
        if np.shape(self.base) != (n, 3) or np.shape(self.attach) != (n, 3):
            raise ValueError(
                f"Geometry: base and attach must be (n, 3), got {np.shape(self.base)} and "
                f"{np.shape(self.attach)}"
            )
        if np.shape(self.dof) != (6, n):
            raise ValueError(f"Geometry: dof must be (6, n) = (6, {n}), got {np.shape(self.dof)}")

    @property
    def n(self) -> int:
        return int(np.shape(self.base)[0])

    def attachment_points(self, pose: Pose) -> Float[Array, "n 3"]:
        """World coordinates of the rod tips at ``pose``."""
        return jnp.asarray(pose.center) + jnp.asarray(self.attach) @ pose.R.T

    def rod_lengths(self, pose: Pose) -> Float[Array, " n"]:
        return jnp.linalg.norm(self.attachment_points(pose) - self.base, axis=-1)

    def jacobian(self, pose: Pose) -> Float[Array, "n n"]:
        """Rod Jacobian ``J = dL/dx`` at ``pose``: ``L̇ = J ẋ`` (m per m or m per rad).

        Row i is ``[n_iᵀ, ((a_i − c) × n_i)ᵀ] · blkdiag(I, R) · dof`` with ``n_i`` the unit
        rod direction from base to tip.
        """
        R = pose.R
        a = self.attachment_points(pose)
        d = a - self.base
        nvec = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
        moment = jnp.cross(a - jnp.asarray(pose.center), nvec)
        rows = jnp.concatenate([nvec, moment], axis=-1)  # (n, 6)
        T = jnp.zeros((6, 6)).at[:3, :3].set(jnp.eye(3)).at[3:, 3:].set(R)
        return rows @ T @ jnp.asarray(self.dof)


def hexagon(radius: float = 0.20) -> np.ndarray:
    """Base hexagon vertices at 0°, 60°, …, 300° (``(6, 3)``, z = 0)."""
    ang = np.deg2rad(np.arange(0, 360, 60))
    return np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(6)], axis=-1)


def dof_matrix(translations: int, rotation_axes: tuple[int, ...]) -> np.ndarray:
    """``(6, n)`` selection: the first ``translations`` world axes, then the given stylus axes."""
    cols = [np.eye(6)[:, i] for i in range(translations)]
    cols += [np.eye(6)[:, 3 + ax] for ax in rotation_axes]
    return np.stack(cols, axis=-1)


def cu5_geometry() -> Geometry:
    """The 5-rod layout of docs/device.md: rods to front A from 60°, 180°, 300°; to rear B from
    120°, 240°; A = c + 0.04 x̂, B = c − 0.12 x̂; DOF = 3 translations + rotations about ŷ, ẑ."""
    hexa = hexagon()
    base = hexa[[1, 3, 5, 2, 4]]
    A, B = np.array([0.04, 0.0, 0.0]), np.array([-0.12, 0.0, 0.0])
    attach = np.stack([A, A, A, B, B])
    return Geometry(jnp.asarray(base), jnp.asarray(attach), jnp.asarray(dof_matrix(3, (1, 2))))


def tripod_geometry() -> Geometry:
    """A 3-rod translational device: rods from base vertices 0°, 120°, 240° meet at the grip."""
    hexa = hexagon()
    base = hexa[[0, 2, 4]]
    return Geometry(jnp.asarray(base), jnp.zeros((3, 3)), jnp.asarray(dof_matrix(3, ())))


def quad_geometry() -> Geometry:
    """A 4-rod layout: cu5 without its 240° rod — rods to the front attachment
    A = c + 0.04 x̂ from the 60°, 180° and 300° vertices, one rod to the rear B = c − 0.12 x̂
    from 120°; DOF = 3 translations + pitch (rotation about the stylus' ŷ axis). Yaw and roll
    are not controlled (not part of the model). cond(J) at home with rotations scaled by
    0.1 m ≈ 5.0 (cu5 ≈ 5.9, tripod3 ≈ 4.2); controlling yaw (ẑ) instead with these rods gives
    ≈ 6.2 at home but up to ≈ 9 within ±5 cm, pitch ≤ 5.6 there."""
    hexa = hexagon()
    base = hexa[[1, 3, 5, 2]]
    A, B = np.array([0.04, 0.0, 0.0]), np.array([-0.12, 0.0, 0.0])
    attach = np.stack([A, A, A, B])
    return Geometry(jnp.asarray(base), jnp.asarray(attach), jnp.asarray(dof_matrix(3, (1,))))


def hexapod_geometry() -> Geometry:
    """A 6-rod, 6-DOF device: three rods to a small front ring (r = 30 mm, x = +0.04 m) and
    three to a rear ring (x = −0.12 m), so roll about the stylus is controlled too."""
    hexa = hexagon()
    r = 0.03
    front = [np.array([0.04, r * np.cos(t), r * np.sin(t)]) for t in np.deg2rad([90, 210, 330])]
    rear = [np.array([-0.12, r * np.cos(t), r * np.sin(t)]) for t in np.deg2rad([30, 150, 270])]
    base = hexa[[1, 3, 5, 0, 2, 4]]
    attach = np.stack(front + rear)
    return Geometry(jnp.asarray(base), jnp.asarray(attach), jnp.asarray(dof_matrix(3, (0, 1, 2))))
