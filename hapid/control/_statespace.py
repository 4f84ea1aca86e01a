# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Continuous-time state-space value object and closed-loop poles.

A ``StateSpace`` ``(A, B, C, D)`` realizes ``H(s) = C (sI − A)⁻¹ B + D`` with time in
seconds (``s`` in rad/s). Shapes: ``A (nx, nx)``, ``B (nx, m)``, ``C (p, nx)``, ``D (p, m)``;
leading batch dimensions are allowed for ``vmap``.

The closed-loop poles of a negative-feedback loop ``u = G (r − y)``, ``y = P u`` are the
independent cross-check of the frequency-domain (generalized Nyquist) verdict of
:func:`hapid.control.analyze_loop`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Complex, Float, Int

from .. import _config  # noqa: F401  (float64)


class StateSpace(eqx.Module):
    """A real continuous-time state-space system ``ẋ = A x + B u``, ``y = C x + D u``."""

    A: Float[Array, "... nx nx"]
    B: Float[Array, "... nx m"]
    C: Float[Array, "... p nx"]
    D: Float[Array, "... p m"]

    def __check_init__(self):
        a, b, c, d = (np.shape(x) for x in (self.A, self.B, self.C, self.D))
        if len(a) < 2 or a[-1] != a[-2]:
            raise ValueError(f"StateSpace: A must be square, got {a}")
        if b[-2] != a[-1] or c[-1] != a[-1] or d[-2] != c[-2] or d[-1] != b[-1]:
            raise ValueError(f"StateSpace: inconsistent shapes A{a} B{b} C{c} D{d}")

    @property
    def n_states(self) -> int:
        return int(np.shape(self.A)[-1])

    @property
    def n_inputs(self) -> int:
        return int(np.shape(self.B)[-1])

    @property
    def n_outputs(self) -> int:
        return int(np.shape(self.C)[-2])

    def __call__(self, s: Complex[Array, " N"]) -> Complex[Array, "N p m"]:
        """Transfer matrix ``C (sI − A)⁻¹ B + D`` at complex ``s`` (rad/s), ``(N, p, m)``."""
        s = jnp.asarray(s, dtype=jnp.complex128)
        nx = self.n_states
        eye = jnp.eye(nx, dtype=jnp.complex128)
        sIA = s[:, None, None] * eye - self.A[..., None, :, :]
        X = jnp.linalg.solve(
            sIA,
            jnp.broadcast_to(self.B[..., None, :, :], sIA.shape[:-1] + (self.n_inputs,)).astype(
                jnp.complex128
            ),
        )
        return self.C[..., None, :, :] @ X + self.D[..., None, :, :]

    def at_omega(self, omega: Float[Array, " N"]) -> Complex[Array, "N p m"]:
        """Frequency response on ``s = jω`` (ω in rad/s), ``(N, p, m)``."""
        return self(1j * jnp.asarray(omega))

    def poles(self) -> Complex[Array, " nx"]:
        """Eigenvalues of ``A`` (rad/s)."""
        return jnp.linalg.eigvals(self.A)

    def n_unstable_poles(self, tol: float = 0.0) -> Int[Array, ""]:
        """Number of eigenvalues of ``A`` with real part ``> tol`` (open right half plane)."""
        return jnp.sum(jnp.real(self.poles()) > tol, axis=-1)

    def is_stable(self, tol: float = 0.0) -> Bool[Array, ""]:
        """All eigenvalues of ``A`` strictly left of ``Re s = −tol``."""
        return jnp.all(jnp.real(self.poles()) < -tol, axis=-1)


def series(first: StateSpace, second: StateSpace) -> StateSpace:
    """The cascade ``second ∘ first`` (``u → first → second → y``), i.e. ``H₂(s) H₁(s)``.

    State ordering ``[x₁; x₂]``.
    """
    A1, B1, C1, D1 = first.A, first.B, first.C, first.D
    A2, B2, C2, D2 = second.A, second.B, second.C, second.D
    n1, n2 = A1.shape[-1], A2.shape[-1]
    A = jnp.block([[A1, jnp.zeros((n1, n2))], [B2 @ C1, A2]])
    B = jnp.concatenate([B1, B2 @ D1], axis=0)
    C = jnp.concatenate([D2 @ C1, C2], axis=1)
    return StateSpace(A, B, C, D2 @ D1)


def closed_loop_matrix(plant: StateSpace, controller: StateSpace) -> Float[Array, "nc nc"]:
    """State matrix of the negative-feedback loop ``u = G (r − y)``, ``y = P u``.

    ``plant`` P maps ``m`` inputs to ``p`` outputs; ``controller`` G maps ``p`` to ``m``. With
    feedthroughs, ``u = F (C_G x_G − D_G C_P x_P)``, ``F = (I + D_G D_P)⁻¹``; the loop is
    ill-posed when ``I + D_G D_P`` is singular (check :func:`closed_loop_well_posed`).
    State ordering ``[x_P; x_G]``.
    """
    Ap, Bp, Cp, Dp = plant.A, plant.B, plant.C, plant.D
    Ag, Bg, Cg, Dg = controller.A, controller.B, controller.C, controller.D
    m = Bp.shape[-1]
    F = jnp.linalg.inv(jnp.eye(m) + Dg @ Dp)
    top = jnp.concatenate([Ap - Bp @ F @ Dg @ Cp, Bp @ F @ Cg], axis=1)
    bot = jnp.concatenate([-Bg @ Cp + Bg @ Dp @ F @ Dg @ Cp, Ag - Bg @ Dp @ F @ Cg], axis=1)
    return jnp.concatenate([top, bot], axis=0)


def closed_loop_well_posed(plant: StateSpace, controller: StateSpace, rtol: float = 1e-10):
    """``True`` when ``I + D_G D_P`` is numerically invertible (the loop is well posed)."""
    m = plant.B.shape[-1]
    sv = jnp.linalg.svd(jnp.eye(m) + controller.D @ plant.D, compute_uv=False)
    return sv[-1] > rtol * sv[0]


def closed_loop_poles(plant: StateSpace, controller: StateSpace) -> Complex[Array, " nc"]:
    """Closed-loop poles (rad/s): eigenvalues of :func:`closed_loop_matrix`."""
    return jnp.linalg.eigvals(closed_loop_matrix(plant, controller))


def closed_loop_is_stable(
    plant: StateSpace, controller: StateSpace, tol: float = 0.0
) -> Bool[Array, ""]:
    """Closed loop well posed and every pole has real part ``< −tol``."""
    poles = closed_loop_poles(plant, controller)
    return jnp.all(jnp.real(poles) < -tol) & closed_loop_well_posed(plant, controller)
