# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""The paper's "positizing" (section 5.1) and its closed-right-half-plane root check.

With ``A = V D V⁻¹`` the eigendecomposition of a real square matrix, the paper defines the
positized matrix ``A_P = V |D| V⁻¹``, ``|·|`` elementwise.

Complex eigenvalues. A real matrix has its complex eigenvalues in conjugate pairs with
conjugate eigenvectors, so ``V f(D) V⁻¹`` is *real* for any ``f`` with ``f(λ̄) = conj f(λ)``.
The elementwise modulus is such an ``f`` (``|λ̄| = |λ|`` is real), so the paper's literal
definition already yields a real matrix; we return the real part of the computed product,
which only discards rounding (~1e-16 relative). This is the default, ``mode="modulus"``
(paper-literal): a pair ``a ± jb`` becomes ``√(a²+b²)`` twice, i.e. the rotation within that
invariant plane is replaced by a positive scaling. ``mode="real_part"`` instead maps
``λ → |Re λ| + j Im λ`` (also conjugate-symmetric, so also real), which keeps the rotation and
only flips the sign of a negative real part. For real eigenvalues both modes are exactly the
paper's ``V |D| V⁻¹``. Ill-conditioned (near-defective) ``V`` makes either unreliable, as it
does the paper's formula.

Positizing does not guarantee open-left-half-plane roots (the paper: "usually (but not
always) sufficient"); :func:`crhp_report` counts what is left. hapid's NLS fit avoids the
issue by construction (PD parameterization).
"""

from __future__ import annotations

import enum
from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..impedance import ImpedanceModel, SecondOrder


def positize_matrix(A: Float[Array, "... n n"], mode: str = "modulus") -> Float[Array, "... n n"]:
    """``Re(V g(D) V⁻¹)`` with ``g = |·|`` (``mode="modulus"``) or ``|Re|+j·Im`` (``"real_part"``)."""
    if mode not in ("modulus", "real_part"):
        raise ValueError(f"positize: mode must be 'modulus' or 'real_part', got {mode!r}")
    lam, V = jnp.linalg.eig(A)
    if mode == "modulus":
        g = jnp.abs(lam).astype(lam.dtype)
    else:
        g = jnp.abs(jnp.real(lam)) + 1j * jnp.imag(lam)
    # V g V⁻¹ as a solve: (V g) V⁻¹ = ((V⁻ᵀ)(V g)ᵀ)ᵀ
    Vg = V * g[..., None, :]
    out = jnp.swapaxes(jnp.linalg.solve(jnp.swapaxes(V, -1, -2), jnp.swapaxes(Vg, -1, -2)), -1, -2)
    return jnp.real(out).astype(A.dtype)


def positize(model: ImpedanceModel, mode: str = "modulus") -> ImpedanceModel:
    """Positize M, B, K of both ``hand`` and ``total`` (paper section 5.1); units unchanged.

    See the module docstring for the treatment of complex eigenvalues (``mode``).
    """
    pos = lambda so: SecondOrder(*(positize_matrix(a, mode) for a in (so.M, so.B, so.K)))  # noqa: E731
    return ImpedanceModel(hand=pos(model.hand), total=pos(model.total))


class CRHPStatus(enum.StrEnum):
    """Outcome of :class:`CRHPReport`: which determinant has closed-right-half-plane roots.
    Roots of det Ẑ_H are poles of the inverse-model controller, roots of det Ẑ_T its zeros."""

    OK = "ok"
    HAND = "det Ẑ_H has CRHP roots"
    TOTAL = "det Ẑ_T has CRHP roots"
    BOTH = "det Ẑ_H and det Ẑ_T have CRHP roots"


class CRHPReport(NamedTuple):
    """Number of roots of ``det Ẑ_H(s)`` and ``det Ẑ_T(s)`` with ``Re s ≥ −tol`` (of 2n each)."""

    hand: Int[Array, ...]
    total: Int[Array, ...]

    @property
    def ok(self):
        """True when neither impedance has a closed-right-half-plane root."""
        return (self.hand == 0) & (self.total == 0)

    @property
    def status(self) -> CRHPStatus:
        """:class:`CRHPStatus` (concrete, unbatched counts only)."""
        h, t = int(self.hand) > 0, int(self.total) > 0
        return {(False, False): CRHPStatus.OK, (True, False): CRHPStatus.HAND,
                (False, True): CRHPStatus.TOTAL, (True, True): CRHPStatus.BOTH}[(h, t)]  # fmt: skip

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok`` and the counts ``hand``, ``total``."""
        return {
            "status": self.status.value,
            "ok": bool(self.ok),
            "hand": int(self.hand),
            "total": int(self.total),
        }


def crhp_report(model: ImpedanceModel, tol: float = 0.0) -> CRHPReport:
    """Closed-RHP root counts of ``det(Ẑ_H)`` and ``det(Ẑ_T)`` (``SecondOrder.n_crhp_roots``)."""
    return CRHPReport(hand=model.hand.n_crhp_roots(tol), total=model.total.n_crhp_roots(tol))
