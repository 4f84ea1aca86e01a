"""The shared vocabulary: second-order matrix impedances ``Z(s) = M s² + B s + K``.

Arrays are frequency-first: an impedance evaluated on ``N`` frequencies is ``(N, n, n)``
complex. Frequencies are rad/s internally. Sign conventions are the paper's:
``R_I = −Z_H L``, ``R_A = −Z_T L``, ``Z_T = Z_M + Z_H`` and ``P = Z_H Z_T⁻¹``.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from . import _config  # noqa: F401  (float64)


def _check_square_triplet(M, B, K, name: str) -> None:
    shapes = {np.shape(M), np.shape(B), np.shape(K)}
    if len(shapes) != 1:
        raise ValueError(f"{name}: M, B, K must have the same shape, got {sorted(shapes)}")
    shape = shapes.pop()
    if len(shape) < 2 or shape[-1] != shape[-2]:
        raise ValueError(f"{name}: M, B, K must be square (…, n, n) matrices, got shape {shape}")


class SecondOrder(eqx.Module):
    """A matrix polynomial ``Z(s) = M s² + B s + K`` with real ``(n, n)`` coefficients.

    Units in rod space: M in kg, B in N·s/m, K in N/m. Leading batch dimensions are allowed
    (a batch of models is a ``SecondOrder`` whose arrays are ``(b, n, n)``).
    """

    M: Float[Array, "... n n"]
    B: Float[Array, "... n n"]
    K: Float[Array, "... n n"]

    def __check_init__(self):
        _check_square_triplet(self.M, self.B, self.K, "SecondOrder")

    @property
    def n(self) -> int:
        return int(np.shape(self.M)[-1])

    def __call__(self, s: Complex[Array, " N"]) -> Complex[Array, "N n n"]:
        """Evaluate ``Z(s)`` at complex ``s`` (rad/s), returning ``(N, n, n)``."""
        s = jnp.asarray(s, dtype=jnp.complex128)[..., None, None]
        return self.M[..., None, :, :] * s**2 + self.B[..., None, :, :] * s + self.K[..., None, :, :]

    def at_omega(self, omega: Float[Array, " N"]) -> Complex[Array, "N n n"]:
        """Evaluate on the imaginary axis, ``s = jω`` with ω in rad/s."""
        return self(1j * jnp.asarray(omega))

    def __add__(self, other: SecondOrder) -> SecondOrder:
        return SecondOrder(self.M + other.M, self.B + other.B, self.K + other.K)

    def __sub__(self, other: SecondOrder) -> SecondOrder:
        return SecondOrder(self.M - other.M, self.B - other.B, self.K - other.K)

    def symmetrized(self) -> SecondOrder:
        sym = lambda A: 0.5 * (A + jnp.swapaxes(A, -1, -2))  # noqa: E731
        return SecondOrder(sym(self.M), sym(self.B), sym(self.K))

    def roots(self) -> Complex[Array, " 2n"]:
        """Roots of ``det(M s² + B s + K)`` (rad/s), ``2n`` of them.

        Quadratic eigenvalue problem through the companion linearization
        ``[[0, I], [−M⁻¹K, −M⁻¹B]]``; requires a non-singular M (a singular M has roots at
        infinity, which this returns as very large values).
        """
        n = self.n
        Minv = jnp.linalg.inv(self.M)
        top = jnp.concatenate([jnp.zeros_like(self.M), jnp.broadcast_to(jnp.eye(n), self.M.shape)], -1)
        bot = jnp.concatenate([-Minv @ self.K, -Minv @ self.B], -1)
        return jnp.linalg.eigvals(jnp.concatenate([top, bot], -2))

    def n_crhp_roots(self, tol: float = 0.0) -> Array:
        """Number of roots with real part ≥ ``-tol`` (closed right half plane)."""
        return jnp.sum(jnp.real(self.roots()) >= -tol, axis=-1)


class ImpedanceModel(eqx.Module):
    """Hand and total impedance models, the pair a controller is designed from.

    ``hand`` is Ẑ_H, ``total`` is Ẑ_T (``mechanism`` = Ẑ_T − Ẑ_H). ``P̂(s) = Ẑ_H Ẑ_T⁻¹``.
    """

    hand: SecondOrder
    total: SecondOrder

    def __check_init__(self):
        if np.shape(self.hand.M) != np.shape(self.total.M):
            raise ValueError(
                f"ImpedanceModel: hand and total must have the same shape, got "
                f"{np.shape(self.hand.M)} and {np.shape(self.total.M)}"
            )

    @classmethod
    def from_hand_mechanism(cls, hand: SecondOrder, mechanism: SecondOrder) -> ImpedanceModel:
        return cls(hand=hand, total=hand + mechanism)

    @property
    def n(self) -> int:
        return self.hand.n

    @property
    def mechanism(self) -> SecondOrder:
        return self.total - self.hand

    def Z_H(self, s):
        return self.hand(s)

    def Z_T(self, s):
        return self.total(s)

    def P(self, s) -> Complex[Array, "N n n"]:
        """Plant model ``P̂(s) = Ẑ_H(s) Ẑ_T(s)⁻¹`` (``(N, n, n)``)."""
        return plant(self.hand(s), self.total(s))

    def P_inv(self, s) -> Complex[Array, "N n n"]:
        """``P̂⁻¹(s) = Ẑ_T(s) Ẑ_H(s)⁻¹``."""
        return plant(self.total(s), self.hand(s))


def plant(Z_H: Complex[Array, "N n n"], Z_T: Complex[Array, "N n n"]) -> Complex[Array, "N n n"]:
    """``P = Z_H Z_T⁻¹`` per frequency, computed as a solve (``(Z_T^T \\ Z_H^T)^T``)."""
    return jnp.swapaxes(jnp.linalg.solve(jnp.swapaxes(Z_T, -1, -2), jnp.swapaxes(Z_H, -1, -2)), -1, -2)


def singular_values(A: Complex[Array, "N n n"]) -> Float[Array, "N n"]:
    """Singular values per frequency, descending, ``(N, n)`` (deadlock-safe, see ``_linalg``)."""
    from ._linalg import svdvals

    return svdvals(A)


def span_db(A: Complex[Array, "N n n"]) -> Float[Array, " N"]:
    """Singular-value span ``20 log10(σ̄/σ̲)`` per frequency in dB."""
    sv = singular_values(A)
    return 20.0 * jnp.log10(sv[..., 0] / sv[..., -1])
