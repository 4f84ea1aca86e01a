# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Characteristic loci and the generalized Nyquist criterion on a frequency grid.

Characteristic loci (MacFarlane & Postlethwaite 1977) are the eigenvalues ``λ_i(jω)`` of the
loop ``L(jω) = P(jω) G(jω)``. ``eig`` returns them in no particular order, so they are
tracked across frequency by matching each frequency's eigenvalues to the previous
frequency's (minimum total squared distance over all permutations for ``n ≤ 6``, greedy
nearest-pair assignment above). The tracking is a ``lax.scan``: jittable and vmappable.

Stability is decided from ``det(I + L) = Π_i (1 + λ_i)``, whose winding number about 0 is
the sum of the loci's encirclements of −1 but needs no tracking (more robust).

Sign convention and assumptions of :func:`nyquist_encirclements`:

* ``N`` is the number of **clockwise** encirclements of the origin by ``det(I + L(s))`` as
  ``s`` travels the standard Nyquist contour (up the imaginary axis, back around the right
  half plane). Then ``N = Z − P_ol``: ``Z`` closed-loop poles in the open RHP, ``P_ol`` the
  open-loop RHP poles of ``P`` and ``G`` together (supplied by the caller). The closed loop
  is stable iff ``N = −P_ol``.
* Real systems: ``det(I + L(−jω)) = conj(det(I + L(jω)))``, so the contour's two halves
  contribute equally and ``N = −(θ(ω_max) − θ(ω_min))/π`` with θ the unwrapped phase.
* The grid must start low enough and end high enough that ``det(I + L)`` is close to its
  (real) values at ω = 0 and ω = ∞ — no poles on the imaginary axis (no integrators), ``L``
  proper. The raw ``N`` is then close to an integer; a residual above 0.2 is flagged.
* The grid must resolve the phase: every step of the unwrapped phase must stay below
  ``max_phase_step`` (default π/2), else the count may be wrong and is flagged.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex

from .. import _config  # noqa: F401  (float64)

_MAX_PERMUTATION_N = 6


class Encirclements(NamedTuple):
    """Result of :func:`nyquist_encirclements`; each 0-d (a leading batch axis under ``vmap``).

    ``n``: clockwise encirclements of 0 by det(I + L) over the full Nyquist contour, rounded
    to an integer (float dtype); ``raw``: the unrounded count; ``resolved`` (bool): the grid
    resolved the phase of det(I + L), reached its real end values (``|raw − n| < 0.2``) and
    det(I + L) is finite.
    """

    n: Array
    raw: Array
    resolved: Array


def _match_permutation(prev, cur, perms):
    # perms: (P, n) int; choose the ordering of `cur` closest to `prev`.
    d = jnp.abs(prev[:, None] - cur[None, :]) ** 2  # (n, n)
    cost = jnp.sum(jnp.take_along_axis(d[None, :, :], perms[:, :, None], axis=2)[..., 0], axis=1)
    best = perms[jnp.argmin(cost)]
    return cur[best]


def _match_greedy(prev, cur):
    n = prev.shape[0]
    d = jnp.abs(prev[:, None] - cur[None, :]) ** 2

    def body(_, carry):
        d, out = carry
        flat = jnp.argmin(d)
        i, j = flat // n, flat % n
        out = out.at[i].set(j.astype(out.dtype))
        d = d.at[i, :].set(jnp.inf).at[:, j].set(jnp.inf)
        return d, out

    _, idx = jax.lax.fori_loop(0, n, body, (d, jnp.zeros(n, dtype=jnp.int32)))
    return cur[idx]


def track_loci(eigs: Complex[Array, "N n"], method: str = "auto") -> Complex[Array, "N n"]:
    """Order eigenvalues ``(N, n)`` so that each column is a continuous locus.

    ``method``: ``"permutation"`` (optimal, n! candidates), ``"greedy"`` or ``"auto"``
    (permutation for ``n ≤ 6``). The first frequency's eigenvalues are sorted by angle
    of ``1 + λ`` for a deterministic start.
    """
    n = eigs.shape[-1]
    if method == "auto":
        method = "permutation" if n <= _MAX_PERMUTATION_N else "greedy"
    first = eigs[0][jnp.argsort(jnp.real(eigs[0]) + 1e-9 * jnp.imag(eigs[0]))]
    if method == "permutation":
        perms = jnp.asarray(np.array(list(itertools.permutations(range(n)))), dtype=jnp.int32)
        match = lambda p, c: _match_permutation(p, c, perms)  # noqa: E731
    elif method == "greedy":
        match = _match_greedy
    else:
        raise ValueError(f"track_loci: unknown method {method!r}")

    def step(prev, cur):
        nxt = match(prev, cur)
        return nxt, nxt

    _, rest = jax.lax.scan(step, first, eigs[1:])
    return jnp.concatenate([first[None], rest], axis=0)


def characteristic_loci(L: Complex[Array, "N n n"], method: str = "auto") -> Complex[Array, "N n"]:
    """Eigenvalues of ``L(jω)`` per frequency, tracked continuously (``(N, n)`` complex)."""
    return track_loci(jnp.linalg.eigvals(L), method=method)


def nyquist_encirclements(
    det_I_plus_L: Complex[Array, " N"], max_phase_step: float = np.pi / 2
) -> Encirclements:
    """Clockwise encirclements of 0 by ``det(I + L)`` over the full Nyquist contour.

    Input: ``det(I + L(jω))`` on an increasing grid ``ω > 0`` (``(N,)``). Returns
    :class:`Encirclements` ``(n, raw, resolved)``: the integer count (as float), the
    unrounded value and whether the grid resolved the phase (see module docstring).
    """
    theta = jnp.unwrap(jnp.angle(det_I_plus_L))
    raw = -(theta[-1] - theta[0]) / jnp.pi
    rounded = jnp.round(raw)
    step_ok = jnp.all(jnp.abs(jnp.diff(theta)) < max_phase_step)
    ends_ok = jnp.abs(raw - rounded) < 0.2
    finite = jnp.all(jnp.isfinite(det_I_plus_L))
    return Encirclements(n=rounded, raw=raw, resolved=step_ok & ends_ok & finite)


def nyquist_verdict(n_encirclements, p_ol, resolved, singular) -> Array:
    """THE stability rule of every loop analysis in hapid:
    ``resolved & ~singular & (n_encirclements == −p_ol)``.

    ``n_encirclements``: clockwise encirclements of 0 by det(I + L) over the full contour;
    ``p_ol``: open-loop unstable poles of plant and controller together; ``resolved``: the
    grid resolved the phase of det(I + L) and of every locus 1 + λᵢ; ``singular``: I + L
    numerically singular at a grid frequency. Jittable (arrays in, bool array out)."""
    return (
        jnp.asarray(resolved)
        & ~jnp.asarray(singular)
        & (jnp.asarray(n_encirclements) == -jnp.asarray(p_ol))
    )
