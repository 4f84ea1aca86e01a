"""The shared vocabulary: second-order matrix impedances ``Z(s) = M s² + B s + K``.

Arrays are frequency-first: an impedance evaluated on ``N`` frequencies is ``(N, n, n)``
complex. Frequencies are rad/s internally. Sign conventions are the paper's:
``R_I = −Z_H L``, ``R_A = −Z_T L``, ``Z_T = Z_M + Z_H`` and ``P = Z_H Z_T⁻¹``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from . import _config  # noqa: F401  (float64)
from ._linalg import svdvals


def _check_square_triplet(M, B, K, name: str) -> None:
    shapes = {np.shape(M), np.shape(B), np.shape(K)}
    if len(shapes) != 1:
        raise ValueError(f"{name}: M, B, K must have the same shape, got {sorted(shapes)}")
    shape = shapes.pop()
    if len(shape) < 2 or shape[-1] != shape[-2]:
        raise ValueError(f"{name}: M, B, K must be square (…, n, n) matrices, got shape {shape}")


@jax.jit
def _evaluate(M, B, K, s):
    """``M s² + B s + K`` ``(..., N, n, n)`` at ``s (N,)`` (one compiled program per shape)."""
    s = s[..., None, None]
    return M[..., None, :, :] * s**2 + B[..., None, :, :] * s + K[..., None, :, :]


@jax.jit
def _roots(M, B, K):
    """:meth:`SecondOrder.roots` of the coefficients (one compiled program per shape)."""
    n = M.shape[-1]
    eye = jnp.broadcast_to(jnp.eye(n, dtype=M.dtype), M.shape)
    zero = jnp.zeros_like(M)
    fro = lambda A: jnp.sqrt(jnp.sum(jnp.abs(A) ** 2, axis=(-2, -1)))  # noqa: E731
    Minv = jnp.linalg.inv(M)
    cond_M = fro(M) * fro(Minv)
    good = jnp.isfinite(cond_M) & (cond_M <= 1e8)  # (...,)
    Minv = jnp.where(good[..., None, None] & jnp.isfinite(Minv), Minv, 0.0)
    top = jnp.concatenate([zero, eye], -1)
    companion = jnp.concatenate([top, jnp.concatenate([-Minv @ K, -Minv @ B], -1)], -2)
    # shift-and-invert of the pencil A − sE (σ in the upper right quadrant: not a root of
    # a stable model, and generically not of any other)
    nM, nB, nK = fro(M), fro(B), fro(K)
    tiny = jnp.finfo(M.dtype).tiny
    w0 = jnp.where(
        (nM > 0) & (nK > 0),
        jnp.sqrt(nK / jnp.maximum(nM, tiny)),
        jnp.where((nB > 0) & (nK > 0), nK / jnp.maximum(nB, tiny), 1.0),
    )
    sigma = (w0 * jnp.exp(1j * np.pi * 0.2371))[..., None, None]
    A = jnp.concatenate([top, jnp.concatenate([-K, -B], -1)], -2).astype(jnp.complex128)
    E = jnp.concatenate(
        [jnp.concatenate([eye, zero], -1), jnp.concatenate([zero, M], -1)], -2
    ).astype(jnp.complex128)
    # one LAPACK kernel at a time (XLA:CPU deadlock, see hapid/_linalg.py)
    A, E = jax.lax.optimization_barrier((A, E, companion))[:2]
    X = jnp.linalg.solve(A - sigma * E, E)
    mu = jnp.linalg.eigvals(jax.lax.optimization_barrier((X, companion))[0])
    big = jnp.max(jnp.abs(mu), axis=-1, keepdims=True)
    at_inf = jnp.abs(mu) <= 1e-10 * big
    s_shift = jnp.where(at_inf, jnp.inf + 0j, sigma[..., 0] + 1.0 / jnp.where(at_inf, 1.0, mu))
    s_comp = jnp.linalg.eigvals(jax.lax.optimization_barrier((companion, mu))[0])
    return jnp.where(good[..., None], s_comp, s_shift)


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
        return _evaluate(self.M, self.B, self.K, jnp.asarray(s, dtype=jnp.complex128))

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
        ``[[0, I], [−M⁻¹K, −M⁻¹B]]`` when M is well conditioned (``‖M‖_F‖M⁻¹‖_F ≤ 1e8``).
        Otherwise (near-singular or singular M, e.g. a PSD fit on the boundary) the pencil
        ``[[0, I], [−K, −B]] − s·diag(I, M)`` is solved by shift-and-invert about a complex
        shift σ (``μ = 1/(s − σ)``), which stays accurate for the finite roots. A singular M
        has roots at *infinity* (``|μ| ≤ 1e-10·max|μ|``, i.e. beyond ~1e10 times the
        nearest root's distance from σ); they are returned as ``inf`` (never as NaN or a
        spurious large finite value), and :meth:`n_crhp_roots` counts them as closed-RHP,
        the conservative reading that ``hapid.control`` uses too.
        """
        return _roots(self.M, self.B, self.K)

    def n_crhp_roots(self, tol: float = 0.0) -> Array:
        """Number of roots with real part ≥ ``-tol`` (closed right half plane); roots at
        infinity (singular M, see :meth:`roots`) and non-finite roots count as closed-RHP."""
        r = self.roots()
        return jnp.sum((jnp.real(r) >= -tol) | ~jnp.isfinite(r), axis=-1)


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


@jax.jit
def plant(Z_H: Complex[Array, "N n n"], Z_T: Complex[Array, "N n n"]) -> Complex[Array, "N n n"]:
    """``P = Z_H Z_T⁻¹`` per frequency, computed as a solve (``(Z_T^T \\ Z_H^T)^T``)."""
    return jnp.swapaxes(
        jnp.linalg.solve(jnp.swapaxes(Z_T, -1, -2), jnp.swapaxes(Z_H, -1, -2)), -1, -2
    )


def singular_values(A: Complex[Array, "N n n"]) -> Float[Array, "N n"]:
    """Singular values per frequency, descending, ``(N, n)`` (deadlock-safe, see ``_linalg``)."""
    return svdvals(A)


def span_db(A: Complex[Array, "N n n"]) -> Float[Array, " N"]:
    """Singular-value span ``20 log10(σ̄/σ̲)`` per frequency in dB."""
    sv = singular_values(A)
    return 20.0 * jnp.log10(sv[..., 0] / sv[..., -1])
