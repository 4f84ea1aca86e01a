# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""The paper's weighted least-squares baseline (section 4.2), all elements in one solve.

For each element ``z_ij`` of Z_H and of Z_T, with ``h(jω) = 1/(jω + ω_c)²``, the weighted
regressor ``A`` (``(N, 3)`` complex) has rows ``h(jω_k)·[(jω_k)², jω_k, 1]`` and the weighted
data is ``z̃_k = h(jω_k) z_ij(jω_k)``. The real 3-vector ``θ_ij = [m_ij, b_ij, k_ij]`` minimizing
``Σ_k |z̃_k − (Aθ)_k|²`` is

    θ_ij = Re(Aᴴ A)⁻¹ Re(Aᴴ z̃),

which is the paper's ``(Re(φ̃ φ̃ᴴ))⁻¹ Re(φ̃ Z̃_ij)`` with ``φ̃ = Aᴴ`` (3 × N). ``A`` is shared by
all ``2n²`` elements (and by every FRF on the same grid), so the fit is the ``3 × N`` complex
operator ``K = (Re AᴴA)⁻¹ Aᴴ diag(h)`` built once and ``θ = Re(K Z)`` as one matmul over every
element (:func:`wls_operator`). Internally the columns of ``A`` are scaled to unit norm before
the (Cholesky) inversion and the scaling is undone after: the same minimizer, computed with a
normal matrix of condition ~10 instead of ~10¹⁰.
"""

from __future__ import annotations

import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jaxtyping import Array, Complex, Float

from .._constants import TWO_PI
from ..frf import FRF
from ..impedance import ImpedanceModel, SecondOrder
from ._checks import band_mask, check_fit_input

OMEGA_C_PAPER = 7.0 * TWO_PI
"""The paper's weighting corner ω_c = 7·2π rad/s (7 Hz)."""


def paper_weight(omega: Float[Array, " N"], omega_c: float = OMEGA_C_PAPER) -> Complex[Array, " N"]:
    """The paper's ``h(jω) = 1/(jω + ω_c)²`` (ω, ω_c in rad/s), shape ``(N,)``."""
    return 1.0 / (1j * omega + omega_c) ** 2


def wls_operator(
    omega: Float[Array, " N"],
    omega_c: float = OMEGA_C_PAPER,
    mask: Float[Array, " N"] | None = None,
) -> Complex[Array, "3 N"]:
    """The paper WLS as a linear map: ``K`` ``(3, N)`` complex with ``θ = Re(K z)``.

    ``θ = [m, b, k]`` of any element ``z`` ``(N,)`` of an FRF on the grid ``omega`` (rad/s);
    ``K = diag(1/c)·G⁻¹·A_sᴴ·diag(h)`` with ``A_s`` the column-scaled weighted regressor and
    ``G = Re(A_sᴴ A_s)`` its (3 × 3, condition ~10) normal matrix. ``K`` depends only on the
    grid, ``ω_c`` and the band ``mask`` (``(N,)``, 0/1): one ``K`` serves all ``2n²`` elements of
    every FRF on that grid.
    """
    s = 1j * omega
    h = paper_weight(omega, omega_c)
    if mask is not None:
        h = h * mask
    A = h[:, None] * jnp.stack([s**2, s, jnp.ones_like(s)], axis=-1)  # (N, 3)
    c = jnp.linalg.norm(A, axis=0)  # column norms
    A_s = A / c
    G = jnp.real(jnp.conj(A_s).T @ A_s)  # (3, 3) real, SPD
    G_inv = jsl.cho_solve(jsl.cho_factor(G, lower=True), jnp.eye(3, dtype=G.dtype))
    return (G_inv @ (jnp.conj(A_s).T * h[None, :])) / c[:, None]


def wls_coefficients(
    omega: Float[Array, " N"],
    Z: Complex[Array, "N ..."],
    omega_c: float = OMEGA_C_PAPER,
    mask: Float[Array, " N"] | None = None,
) -> Float[Array, "3 ..."]:
    """Per-element paper WLS: ``(3, ...)`` real ``[m, b, k]`` for every trailing element of Z.

    ``omega`` (rad/s) is ``(N,)``, ``Z`` is ``(N, ...)`` complex (any trailing shape: the
    elements of one FRF, or of a batch of FRFs on the same grid, frequency first);
    ``mask`` (``(N,)``, 0/1) drops frequencies, equivalent to removing those rows. One
    ``(3, N) × (N, E)`` complex matmul with :func:`wls_operator` for all ``E`` elements.
    """
    K = wls_operator(omega, omega_c, mask)
    flat = Z.reshape(Z.shape[0], -1)
    theta = jnp.real(K @ flat)
    return theta.reshape((3,) + Z.shape[1:])


def wls(frf: FRF, omega_c: float = OMEGA_C_PAPER, f_max_hz: float | None = None) -> ImpedanceModel:
    """The paper's section 4.2 fit: Z_H → ``hand``, Z_T → ``total`` (element by element).

    Arguments: ``frf`` with ``omega`` ``(N,)`` rad/s and ``Z_H``, ``Z_T`` ``(N, n, n)`` N/m;
    ``omega_c`` the weight's corner in rad/s (paper: 7·2π); ``f_max_hz`` keeps only
    frequencies ≤ f_max_hz (Hz; ``None`` = all, as in the paper).

    Returns an :class:`ImpedanceModel` with unconstrained (generally non-symmetric) M, B, K
    in kg, N·s/m, N/m. Jittable; ``jax.vmap(wls)`` fits a batch of FRFs. Raises
    ``ValueError`` (outside ``jit``) on non-finite data or fewer than 3 frequencies in band.
    """
    check_fit_input(frf, f_max_hz, what="wls")
    mask = band_mask(frf.omega, f_max_hz) if f_max_hz is not None else None
    Z = jnp.stack([frf.Z_H, frf.Z_T], axis=1)  # (N, 2, n, n)
    m, b, k = wls_coefficients(frf.omega, Z, omega_c, mask)  # each (2, n, n)
    return ImpedanceModel(hand=SecondOrder(m[0], b[0], k[0]), total=SecondOrder(m[1], b[1], k[1]))
