# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Loop building blocks on a frequency grid: ``L``, ``S``, ``T``, the isotropic-bandwidth
crossings, and the helpers the loop results share (input checks, scalar fields).

Everything here is pure ``jnp`` on arrays ``(N, n, n)`` (frequency first), so it can be
``jit``-ed and ``vmap``-ed. Conventions are the paper's: negative feedback, ``L = P G``,
``T = (I + L)⁻¹ L`` (desired → interaction force), ``S = I − T``. The production verdict and
metrics are :func:`hapid.control.loop_metrics` (:mod:`._metrics`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _config  # noqa: F401  (float64)
from .._plain import jsonable
from ._status import LoopStatus

ISO_THRESHOLD = 1.0 - 1.0 / np.sqrt(2.0)
"""``1 − 1/√2 ≈ 0.293``: the paper's isotropic-bandwidth threshold on σ̄(T − I)."""


class LoopMatrices(NamedTuple):
    """The loop's frequency responses (:func:`loop_matrices`), each ``(N, n, n)`` complex
    (dimensionless ratios, frequency first): ``L = P G``, ``S = (I + L)⁻¹`` (sensitivity),
    ``T = I − S = (I + L)⁻¹ L`` (complementary sensitivity)."""

    L: Array
    S: Array
    T: Array


def loop_matrices(P, G) -> LoopMatrices:
    """:class:`LoopMatrices` ``L = P G``, ``S = (I + L)⁻¹`` and ``T = I − S = (I + L)⁻¹ L``
    of plant and controller responses ``P``, ``G`` ``(N, n, n)`` (each ``(N, n, n)``)."""
    L = P @ G
    n = L.shape[-1]
    eye = jnp.eye(n, dtype=L.dtype)
    S = jnp.linalg.solve(eye + L, jnp.broadcast_to(eye, L.shape))
    T = eye - S
    return LoopMatrices(L=L, S=S, T=T)


def _first_crossing(x, omega, thr):
    """Lowest ω where ``x`` reaches ``thr`` (interpolated in log ω); 0 if at the first
    point, inf if never."""
    above = x >= thr
    k = jnp.argmax(above)
    km = jnp.maximum(k - 1, 0)
    xa, xb = x[km], x[k]
    t = jnp.clip((thr - xa) / jnp.where(xb != xa, xb - xa, 1.0), 0.0, 1.0)
    lw = jnp.log(omega)
    w = jnp.exp(lw[km] + t * (lw[k] - lw[km]))
    return jnp.where(~jnp.any(above), jnp.inf, jnp.where(k == 0, 0.0, w))


def _last_crossing(x, omega, thr):
    """Highest ω where ``x < thr`` (end of the last sub-threshold stretch, interpolated);
    inf if below at the last point, 0 if never below."""
    below = x < thr
    N = x.shape[0]
    j = N - 1 - jnp.argmax(below[::-1])
    jp = jnp.minimum(j + 1, N - 1)
    xa, xb = x[j], x[jp]
    t = jnp.clip((thr - xa) / jnp.where(xb != xa, xb - xa, 1.0), 0.0, 1.0)
    lw = jnp.log(omega)
    w = jnp.exp(lw[j] + t * (lw[jp] - lw[j]))
    return jnp.where(~jnp.any(below), 0.0, jnp.where(j == N - 1, jnp.inf, w))


class IsotropicBandwidth(NamedTuple):
    """Crossings of σ̄(T − I) through the threshold (:func:`isotropic_bandwidth`), each a
    0-d float array in rad/s.

    ``lowest``: lowest ω where σ̄(T − I) reaches the threshold (log-frequency interpolation;
    ``0`` if already reached at the first grid point, ``inf`` if never on the grid);
    ``literal``: the paper's "maximum ω where σ̄(T − I) < threshold", the end of the last
    sub-threshold stretch (``inf`` if below at the last grid point, ``0`` if never below).
    """

    lowest: Array
    literal: Array


def isotropic_bandwidth(
    sv_T_minus_I: Float[Array, "N n"], omega: Float[Array, " N"], threshold: float = ISO_THRESHOLD
) -> IsotropicBandwidth:
    """:class:`IsotropicBandwidth` (lowest crossing, paper-literal last crossing) of
    σ̄(T − I) (singular values ``(N, n)``, largest first) through ``threshold`` on the grid
    ``omega`` (rad/s, ``(N,)``). Does not check stability."""
    top = sv_T_minus_I[:, 0]
    return IsotropicBandwidth(
        lowest=_first_crossing(top, omega, threshold), literal=_last_crossing(top, omega, threshold)
    )


def scalar_fields(report, names) -> dict:
    """``{name: python value}`` of a loop report's scalar fields (lists when batched); the
    encirclement counts as integers."""
    out = {}
    for name in names:
        v = np.asarray(getattr(report, name))
        if name in ("n_encirclements", "n_closed_loop_rhp"):
            v = v.astype(np.int64)
        out[name] = v.tolist()
    return out


def report_numbers(report, names) -> dict:
    """:func:`scalar_fields` of ``names``, then ``status`` (the :class:`LoopStatus` value, a
    list of them when batched) and ``ok`` — the ``numbers()`` of every loop report."""
    st = report.status
    return scalar_fields(report, names) | {
        "status": st.value if isinstance(st, LoopStatus) else jsonable(st.tolist()),
        "ok": np.asarray(report.ok).tolist(),
    }


def loop_arrays(P, G, omega, who: str):
    """``(P, G, omega)`` as complex128 / float64 arrays, checked: ``P`` and ``G`` both
    ``(N, n, n)``, ``omega (N,)``; a ``ValueError`` naming ``who`` otherwise."""
    P = jnp.asarray(P, dtype=jnp.complex128)
    G = jnp.asarray(G, dtype=jnp.complex128)
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if P.ndim != 3 or P.shape != G.shape or P.shape[-1] != P.shape[-2]:
        raise ValueError(f"{who}: P and G must both be (N, n, n), got {P.shape}, {G.shape}")
    if omega.shape != P.shape[:1]:
        raise ValueError(f"{who}: omega must be (N,) = {P.shape[:1]}, got {omega.shape}")
    return P, G, omega
