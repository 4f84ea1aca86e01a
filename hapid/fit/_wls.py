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

A batch of FRFs on one grid, batch first (``(B, N, ...)``), has a faster path than the complex
GEMM: :func:`wls_batch_coefficients` computes only the real part ``Re(K z) = K_r z_r − K_i z_i``
in one fused pass over Z, complex or given as ``(re, im)`` float pairs (see its docstring).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
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


_UNROLL_MAX_N = 64
"""Up to this many frequencies the batched kernel sums over them unrolled (trace size ∝ N);
above it, the complex GEMM (``einsum``)."""

_KERNEL_OPTIONS = {"xla_cpu_prefer_vector_width": 512}
"""XLA:CPU option of the kernels' own programs (:func:`_batch_program`, :func:`_pairs_program`;
no global flag): 512-bit vectors halve the shuffles that split complex128 (or float pairs)
into real and imaginary parts (measured 1.05–1.45×, typically 1.1–1.15×, on the benchmark
machine)."""


def _pairwise_sum(terms: list):
    """Balanced-tree sum (depth log₂ of the count, rounding error of that order)."""
    while len(terms) > 1:
        pairs = [terms[i] + terms[i + 1] for i in range(0, len(terms) - 1, 2)]
        terms = pairs + terms[len(terms) - len(terms) % 2 :]
    return terms[0]


def _apply_real(K: Complex[Array, "3 N"], Z: Complex[Array, "B N E"]) -> Float[Array, "B 3 E"]:
    """``Re(K @ Z[b])`` for every ``b``: ``(B, 3, E)`` real, one fused pass over Z.

    Per output element, ``Σ_k K_r[j, k]·Re Z[b, k, e] − K_i[j, k]·Im Z[b, k, e]`` unrolled over
    ``k`` and summed pairwise: XLA:CPU fuses ``real``/``imag`` of Z into the loop (no float64
    copy of Z), iterates ``b`` outermost so the ``N × E`` block of one FRF stays in L1 while
    its 3 rows are formed (Z is read once from memory), vectorizes over the last axis ``E``,
    and splits ``b`` over the CPU threads when the output is large (≥ 512 KB). The last axis
    of the *output* must be long for the loop to vectorize: reshaping it to ``(…, n, n)``
    inside the same program turns the loop scalar (measured 1.5× slower), hence the flat ``E``.
    """
    N = Z.shape[1]
    if N > _UNROLL_MAX_N:
        return jnp.real(jnp.einsum("jk,bke->bje", K, Z))
    Kr, Ki = jnp.real(K), jnp.imag(K)
    # real/imag of each frequency slice, not of the whole Z: with one user each they fuse into
    # the loop; jnp.real(Z) sliced 28 times is materialized (a float64 copy of Z, measured)
    terms = [
        Kr[:, k, None] * jnp.real(Z[:, k, None, :]) - Ki[:, k, None] * jnp.imag(Z[:, k, None, :])
        for k in range(N)
    ]
    return _pairwise_sum(terms)


def _batch(omega, Z, omega_c, mask):
    real = jnp.finfo(Z.dtype).dtype  # float64 for complex128
    K = wls_operator(omega.astype(real), omega_c, None if mask is None else mask.astype(real))
    return _apply_real(K, Z.reshape(Z.shape[0], Z.shape[1], -1))


_batch_program = partial(jax.jit, compiler_options=_KERNEL_OPTIONS)(_batch)


def _apply_pairs(Kr: Float[Array, "3 N"], Ki: Float[Array, "3 N"], X: Float[Array, "B N ..."]):
    """``Re(K @ z)`` from float pairs: with ``X`` flattened to ``(B, N, M)``, ``X[b, k, 2e]``
    and ``X[b, k, 2e + 1]`` are Re and Im of ``Z[b, k, e]``; returns ``(B, 3, M / 2)``.

    The same fused pass as :func:`_apply_real` (unrolled over ``k``, summed pairwise, ``b``
    outermost, vectorized over ``e``), reading real and imaginary parts as the even and odd
    float64 of each slice (LLVM loads two vectors and splits them with two shuffles)."""
    B, N = X.shape[:2]
    X = X.reshape(B, N, -1)
    if N > _UNROLL_MAX_N:
        re, im = X[..., 0::2], X[..., 1::2]
        return jnp.einsum("jk,bke->bje", Kr, re) - jnp.einsum("jk,bke->bje", Ki, im)
    terms = [
        Kr[:, k, None] * X[:, k, None, 0::2] - Ki[:, k, None] * X[:, k, None, 1::2]
        for k in range(N)
    ]
    return _pairwise_sum(terms)


def _pairs_inline(omega, X, omega_c, mask):
    """The float-pair kernel with ``K`` built in the program (as :func:`_batch` does)."""
    real = X.dtype
    K = wls_operator(omega.astype(real), omega_c, None if mask is None else mask.astype(real))
    return _apply_pairs(jnp.real(K), jnp.imag(K), X)


_pairs_program = partial(jax.jit, compiler_options=_KERNEL_OPTIONS)(_pairs_inline)
"""The float-pair kernel as its own program (512-bit vectors)."""


def _check_batch_shapes(omega, Z, mask, float_pairs: bool) -> None:
    """Shapes of the grid, data and mask (and the pair axis with ``float_pairs``)."""
    name = "wls_batch_coefficients"
    w_shape = omega.shape if hasattr(omega, "shape") else np.shape(omega)
    z_shape = Z.shape if hasattr(Z, "shape") else np.shape(Z)
    if len(w_shape) != 1:
        raise ValueError(f"{name}: omega must be (N,), got shape {w_shape}")
    N = w_shape[0]
    if len(z_shape) < 2 or z_shape[1] != N:
        raise ValueError(
            f"{name}: Z must be (B, N, ...) with N = len(omega) = {N}, got shape {z_shape}"
        )
    if mask is not None and np.shape(mask) != (N,):
        raise ValueError(f"{name}: mask must be (N,) = ({N},), got shape {np.shape(mask)}")
    if float_pairs:
        dtype = jnp.result_type(Z)
        if not jnp.issubdtype(dtype, jnp.floating):
            raise ValueError(f"{name}: float_pairs=True needs real floating Z, got {dtype}")
        if len(z_shape) < 3 or z_shape[-1] % 2:
            raise ValueError(
                f"{name}: float_pairs=True needs Z (B, N, ..., 2m) with (re, im) pairs on an "
                f"even last axis, got shape {z_shape}"
            )


def _check_batch_values(omega, omega_c, mask) -> None:
    """Finite grid, corner and mask, corner > 0 (concrete input only)."""
    name = "wls_batch_coefficients"
    for label, a in (("omega", omega), ("omega_c", omega_c), ("mask", mask)):
        if a is not None and not isinstance(a, jax.core.Tracer):
            if not np.isfinite(np.asarray(a)).all():
                raise ValueError(f"{name}: {label} contains NaN or inf")
    if not isinstance(omega_c, jax.core.Tracer) and not np.asarray(omega_c) > 0:
        raise ValueError(f"{name}: omega_c must be > 0 rad/s, got {omega_c}")


def _check_finite_result(finite, Z) -> None:
    """A NaN or inf in Z reaches θ (every weight multiplies it; a masked frequency's zero
    weight times NaN or inf is NaN), so ``finite`` — whether θ (3/N of Z's size) is finite — is
    checked, and Z only when it is not, to name the first bad entry. A finite Z passes (also
    when θ overflows)."""
    if finite:
        return
    bad = np.argwhere(~np.isfinite(np.asarray(Z)))
    if len(bad):
        raise ValueError(
            "wls_batch_coefficients: Z contains NaN or inf (first at index "
            f"{tuple(int(i) for i in bad[0])})"
        )


def wls_batch_coefficients(
    omega: Float[Array, " N"],
    Z: Complex[Array, "B N ..."],
    omega_c: float = OMEGA_C_PAPER,
    mask: Float[Array, " N"] | None = None,
    *,
    float_pairs: bool = False,
) -> Float[Array, "B 3 E"]:
    """Per-element paper WLS of a batch of FRFs on one grid, batch first: ``(B, 3, E)`` real.

    ``omega`` (rad/s) is ``(N,)``; ``Z`` is ``(B, N, ...)`` complex — FRF ``b`` frequency
    first, any trailing element shape (e.g. ``(2, n, n)`` for Z_H and Z_T stacked), N/m;
    ``mask`` (``(N,)``, 0/1) drops frequencies. Returns ``θ[b, j, e]`` = ``[m, b, k][j]`` of
    element ``e`` of ``Z[b, k].ravel()`` (kg, N·s/m, N/m); ``θ.reshape(B, 3, *Z.shape[2:])``
    gives the matrices. Same values as :func:`wls_coefficients` (to rounding: the sum over
    frequencies is taken in another order).

    ``float_pairs=True``: ``Z`` is real ``(B, N, ..., 2m)`` holding the same data as float
    pairs, ``Z[..., 2i]`` and ``Z[..., 2i + 1]`` the real and imaginary parts (what
    ``Zc.view(np.float64)`` gives for a complex ``Zc``); then ``E = Z[0, 0].size / 2``.

    How it runs: the real part only, ``Re(K z) = K_r z_r − K_i z_i``, in one fused pass over Z
    (:func:`_apply_real` on complex data, :func:`_apply_pairs` on float pairs), called on its
    own as its own program with 512-bit vectors (θ is then checked for NaN/inf on the host);
    traced inside a ``jit`` it is inlined into the caller's program. For more than 64
    frequencies, a GEMM (``einsum``). benchmarks/README.md ("Batched WLS") has the
    measurements, including a zero-copy float view of complex input and multiply-adds on the
    interleaved pairs, measured and not kept (no faster once complete).

    Raises ``ValueError`` on wrong shapes (``Z`` not ``(B, N, ...)``, ``mask`` not ``(N,)``, an
    odd or missing pair axis with ``float_pairs``) and, outside ``jit``, on NaN or inf in
    ``omega``, ``omega_c``, ``mask`` or ``Z`` (Z through the result: see
    :func:`_check_finite_result`).
    """
    _check_batch_shapes(omega, Z, mask, float_pairs)
    _check_batch_values(omega, omega_c, mask)
    args = (omega, Z, omega_c, mask)
    if any(isinstance(a, jax.core.Tracer) for a in args):
        # inside a jit/vmap: inlined (compiler options apply to top-level programs only)
        return _pairs_inline(*args) if float_pairs else _batch(*args)
    if float_pairs:
        X = Z if isinstance(Z, jax.Array) else np.ascontiguousarray(Z)  # reshaped in the program
        theta = _pairs_program(omega, X, omega_c, mask)
    else:
        theta = _batch_program(*args)
    # the NaN check on θ (3/N of Z's size) on the host: +4 % (paired A/B); a reduction in the
    # program cost more
    _check_finite_result(np.isfinite(np.asarray(theta)).all(), Z)
    return theta


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
