# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""Positive (semi)definite parameterization of hand and mechanism impedances.

Each of the six symmetric matrices ``M_H, B_H, K_H, M_M, B_M, K_M`` (hand, then mechanism)
is written ``A = L Lᵀ (+ eps·I)`` with ``L`` lower triangular. The diagonal of ``L`` has a
free sign: ``L Lᵀ`` is PSD whatever the sign, and the optimum may sit on the PSD boundary,
where an exp/softplus diagonal would make Levenberg–Marquardt crawl for thousands of steps
(docs/conventions.md, "Cholesky details that matter"). The total impedance is ``Z_T = Z_M + Z_H``.

The unconstrained vector ``theta`` has length ``6·n(n+1)/2`` (90 for n = 5): six blocks of
``n(n+1)/2`` lower-triangle entries in ``numpy.tril_indices`` (row-major) order, in the order
``M_H, B_H, K_H, M_M, B_M, K_M``.

``theta`` lives in *scaled* units (see :class:`Scale`): with ``s̃ = s/ω_ref`` and
``Z̃ = Z/z_ref``, ``Z̃ = M̃ s̃² + B̃ s̃ + K̃`` where ``M̃ = M ω_ref²/z_ref``,
``B̃ = B ω_ref/z_ref``, ``K̃ = K/z_ref``. This keeps all entries O(1) and the normal
equations well conditioned. ``Scale(1, 1)`` gives physical units (kg, N·s/m, N/m).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ..impedance import ImpedanceModel, SecondOrder

MATRIX_NAMES = ("M_H", "B_H", "K_H", "M_M", "B_M", "K_M")


class Scale(eqx.Module):
    """Reference frequency ``omega_ref`` (rad/s) and impedance magnitude ``z_ref`` (N/m).

    Scalars (or ``(b,)`` for a batch). ``Scale(1.0, 1.0)`` is the identity scaling.
    """

    omega_ref: Float[Array, ...]
    z_ref: Float[Array, ...]

    @classmethod
    def identity(cls) -> Scale:
        return cls(jnp.asarray(1.0), jnp.asarray(1.0))

    def factors(self) -> tuple[Array, Array, Array]:
        """Multipliers taking physical (M, B, K) to scaled (M̃, B̃, K̃)."""
        return (self.omega_ref**2 / self.z_ref, self.omega_ref / self.z_ref, 1.0 / self.z_ref)


def n_params(n: int) -> int:
    """Length of ``theta`` for an ``n``-rod device: ``6·n(n+1)/2``."""
    return 6 * (n * (n + 1) // 2)


def n_from_params(p: int) -> int:
    """Inverse of :func:`n_params`; ``ValueError`` if ``p`` is not ``6·n(n+1)/2``."""
    t, rem = divmod(p, 6)
    n = int(round((np.sqrt(8 * t + 1) - 1) / 2))
    if rem or n * (n + 1) // 2 != t:
        raise ValueError(f"theta has length {p}, which is not 6·n(n+1)/2 for any integer n")
    return n


def _tril_to_matrix(v: Float[Array, " t"], n: int) -> Float[Array, "n n"]:
    rows, cols = np.tril_indices(n)
    return jnp.zeros((n, n), dtype=v.dtype).at[rows, cols].set(v)


def theta_to_factors(theta: Float[Array, " p"], n: int) -> Float[Array, "6 n n"]:
    """The six lower-triangular factors ``L`` (``(6, n, n)``) from ``theta``."""
    t = n * (n + 1) // 2
    return jnp.stack([_tril_to_matrix(theta[k * t : (k + 1) * t], n) for k in range(6)])


def theta_to_scaled(theta: Float[Array, " p"], n: int, eps: float = 0.0) -> Float[Array, "6 n n"]:
    """The six scaled matrices ``L Lᵀ + eps·I`` (``(6, n, n)``, order of ``MATRIX_NAMES``)."""
    L = theta_to_factors(theta, n)
    return L @ jnp.swapaxes(L, -1, -2) + eps * jnp.eye(n)


def scaled_to_model(mats: Float[Array, "6 n n"], scale: Scale) -> ImpedanceModel:
    """Physical :class:`ImpedanceModel` from scaled hand/mechanism matrices."""
    fm, fb, fk = scale.factors()
    hand = SecondOrder(mats[0] / fm, mats[1] / fb, mats[2] / fk)
    mech = SecondOrder(mats[3] / fm, mats[4] / fb, mats[5] / fk)
    return ImpedanceModel.from_hand_mechanism(hand, mech)


def scaled_pair(
    mats: Float[Array, "6 n n"], s: Complex[Array, " N"]
) -> tuple[Complex[Array, "N n n"], Complex[Array, "N n n"]]:
    """``(Ẑ_H, Ẑ_T)`` ``(N, n, n)`` of the six scaled matrices (:func:`theta_to_scaled`) at the
    scaled Laplace variable ``s = jω/ω_ref`` ``(N,)``; ``Ẑ_T = Ẑ_H + Ẑ_M``."""
    s = s[:, None, None]
    ZH = mats[0] * s**2 + mats[1] * s + mats[2]
    ZT = ZH + mats[3] * s**2 + mats[4] * s + mats[5]
    return ZH, ZT


def theta_to_model(
    theta: Float[Array, " p"], scale: Scale | None = None, eps: float = 0.0
) -> ImpedanceModel:
    """The physical model (kg, N·s/m, N/m) represented by ``theta`` in ``scale`` units.

    ``eps`` (scaled units) adds ``eps·I`` to every matrix, making them strictly PD.
    """
    n = n_from_params(int(np.shape(theta)[-1]))
    scale = Scale.identity() if scale is None else scale
    return scaled_to_model(theta_to_scaled(theta, n, eps), scale)


def model_to_scaled(model: ImpedanceModel, scale: Scale) -> Float[Array, "6 n n"]:
    """Scaled hand and mechanism matrices (``(6, n, n)``) of a physical model."""
    fm, fb, fk = scale.factors()
    h, m = model.hand, model.mechanism
    return jnp.stack([h.M * fm, h.B * fb, h.K * fk, m.M * fm, m.B * fb, m.K * fk])


def model_to_theta(
    model: ImpedanceModel, scale: Scale | None = None, floor: float = 1e-6
) -> Float[Array, " p"]:
    """``theta`` of a model: each scaled matrix projected PD, then its Cholesky factor.

    The six matrices ``M_H, B_H, K_H, M_M, B_M, K_M`` are taken in ``scale`` units (all
    O(1)) and symmetrized; eigenvalues are clipped from below at ``floor`` × that matrix's
    largest |eigenvalue| and at ``floor·1e-3`` × the largest of all six (so an all-zero
    matrix — a mechanism of a single impedance loaded as ``Z_H = Z_T``, or a hand of
    ``Z_H = 0`` — becomes a small multiple of I that the solver can move off, instead of a
    NaN Cholesky factor). The mechanism is ``total − hand`` of the given model, never
    re-derived after a floor was added to the total (which rounds the floor away).

    The Cholesky factors have positive diagonals; any sign pattern represents the same model.
    """
    scale = Scale.identity() if scale is None else scale
    mats = model_to_scaled(model, scale)
    mats = _project_matrix(mats, floor, global_floor=floor * 1e-3)
    # a final symmetrization guards the Cholesky against rounding
    mats = 0.5 * (mats + jnp.swapaxes(mats, -1, -2))
    L = jnp.linalg.cholesky(mats)
    n = model.n
    rows, cols = np.tril_indices(n)
    return L[:, rows, cols].reshape(-1)


def canonical_theta(theta: Float[Array, " p"]) -> Float[Array, " p"]:
    """Flip column signs of each factor so every diagonal of ``L`` is ≥ 0 (same model)."""
    n = n_from_params(int(np.shape(theta)[-1]))
    L = theta_to_factors(theta, n)
    sign = jnp.where(jnp.diagonal(L, axis1=-2, axis2=-1) < 0, -1.0, 1.0)
    L = L * sign[:, None, :]
    rows, cols = np.tril_indices(n)
    return L[:, rows, cols].reshape(-1)


def _project_matrix(
    A: Float[Array, "... n n"], floor: float, global_floor: float | None = None
) -> Float[Array, "... n n"]:
    """Symmetrize and clip eigenvalues at ``floor·max|λ|`` of each matrix; with
    ``global_floor`` also at ``global_floor·max|λ|`` over the stack (axis ``-3``)."""
    A = 0.5 * (A + jnp.swapaxes(A, -1, -2))
    lam, V = jnp.linalg.eigh(A)
    top = jnp.max(jnp.abs(lam), axis=-1, keepdims=True)
    lo = floor * top
    if global_floor is not None:
        lo = jnp.maximum(lo, global_floor * jnp.max(top, axis=-2, keepdims=True))
    # an all-zero matrix still gets a tiny absolute floor so the Cholesky exists
    lo = jnp.maximum(lo, jnp.finfo(A.dtype).tiny ** 0.5)
    lam = jnp.maximum(lam, lo)
    return (V * lam[..., None, :]) @ jnp.swapaxes(V, -1, -2)


def project_pd(model: ImpedanceModel, floor: float = 1e-6) -> ImpedanceModel:
    """Nearest-PD version of a model's hand and mechanism matrices (for initialization).

    Each of ``M_H, B_H, K_H`` and ``M_M, B_M, K_M`` (mechanism = total − hand) is symmetrized
    and its eigenvalues clipped from below at ``floor × max|eigenvalue|`` of that matrix;
    the total is re-formed as hand + mechanism, so it is PD too. Units are unchanged.
    """
    proj = lambda so: SecondOrder(*(_project_matrix(a, floor) for a in (so.M, so.B, so.K)))  # noqa: E731
    return ImpedanceModel.from_hand_mechanism(proj(model.hand), proj(model.mechanism))


def boundary_report(model: ImpedanceModel, rtol: float = 1e-6) -> Float[Array, "... 6"]:
    """Which of ``M_H, B_H, K_H, M_M, B_M, K_M`` have an eigenvalue at the PSD boundary.

    Returns a ``(6,)`` bool array (order of ``MATRIX_NAMES``): true when the smallest
    eigenvalue of the symmetric part is ≤ ``rtol`` × the largest magnitude.
    """
    h, m = model.hand, model.mechanism
    mats = jnp.stack([h.M, h.B, h.K, m.M, m.B, m.K], axis=-3)
    lam = jnp.linalg.eigvalsh(0.5 * (mats + jnp.swapaxes(mats, -1, -2)))
    top = jnp.max(jnp.abs(lam), axis=-1)
    return lam[..., 0] <= rtol * top


def boundary_names(flags) -> list[str]:
    """Names of the matrices flagged by :func:`boundary_report` (a single, unbatched report)."""
    return [name for name, f in zip(MATRIX_NAMES, np.asarray(flags), strict=True) if f]
