# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Scenario plants, pre-processed so that the design objective is cheap and LAPACK-free.

With the inverse-model controller ``G = g(s) · Ẑ_T Ẑ_H⁻¹`` (nominal model, fixed) and any
plant ``P`` (a posterior sample ``P̂_s``, a device's true sampled plant at another pose, …)
the loop is ``L = g · Q`` with ``Q = P · [Ẑ_T Ẑ_H⁻¹]`` — and ``Q`` does not depend on the
tuned parameters. Each ``Q(jω) = V Λ V⁻¹`` is diagonalized once (numpy, at the edge), so

    S = (I + gQ)⁻¹ = V (I + gΛ)⁻¹ V⁻¹,   T = V gΛ(I + gΛ)⁻¹ V⁻¹,   λ_i(L) = g λ_i(Q)

are products of small matrices, differentiable in g with no solve or eigendecomposition
inside the gradient. The characteristic loci of ``L`` are exactly ``g λ_i(Q)``.

Discrete design (``ts`` given): the controller's matrix part is the Tustin discretization
of ``Ẑ_T Ẑ_H⁻¹`` (as :func:`hapid.control.discretize_controller`) and g is the matched
pole-zero ``g_d``; the plants must then be sampled plants on ``z = e^{jωt_s}`` (ω ≤ π/t_s).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from ..control import controller_unstable_poles, discretize_state_space, impedance_ratio_state_space
from ..impedance import ImpedanceModel


class Scenarios(eqx.Module):
    """A batch of ``S`` loops ``L_s = g Q_s`` on one grid, diagonalized.

    Fields: ``omega (N,)`` rad/s; ``lam (S, N, n)`` eigenvalues of ``Q``; ``V``, ``Vi``
    ``(S, N, n, n)`` (``Q = V diag(λ) Vi``); ``p_ol (S,)`` open-loop RHP poles of ``P`` and
    of the matrix part (for the Nyquist count in validation); ``ts`` (static, None =
    continuous); ``labels`` (static). ``recon_err`` is the largest relative
    reconstruction error ``‖V Λ Vi − Q‖/‖Q‖`` (a near-defective ``Q`` would show here).
    """

    omega: Float[Array, " N"]
    lam: Complex[Array, "S N n"]
    V: Complex[Array, "S N n n"]
    Vi: Complex[Array, "S N n n"]
    p_ol: Float[Array, " S"]
    recon_err: float = eqx.field(static=True)
    ts: float | None = eqx.field(static=True, default=None)
    labels: tuple = eqx.field(static=True, default=())

    @property
    def n_scenarios(self) -> int:
        return int(self.lam.shape[0])

    def subset(self, idx) -> Scenarios:
        idx = np.asarray(idx)
        labels = tuple(self.labels[i] for i in idx) if self.labels else ()
        return Scenarios(self.omega, self.lam[idx], self.V[idx], self.Vi[idx], self.p_ol[idx],
                         self.recon_err, self.ts, labels)  # fmt: skip


def matrix_part(model: ImpedanceModel, omega, ts: float | None = None) -> np.ndarray:
    """``Ẑ_T Ẑ_H⁻¹`` on ω: continuous (``ts=None``) or Tustin-discretized, ``(N, n, n)``."""
    omega = np.asarray(omega, dtype=float)
    if ts is None:
        return np.asarray(model.P_inv(1j * omega))
    md = discretize_state_space(impedance_ratio_state_space(model), ts, "tustin")
    z = np.exp(1j * omega * ts)
    A, B, C, D = (np.asarray(x) for x in (md.A, md.B, md.C, md.D))
    eye = np.eye(A.shape[0])
    X = np.linalg.solve(z[:, None, None] * eye - A, np.broadcast_to(B, (z.shape[0],) + B.shape))
    return C @ X + D


def make_scenarios(P, model: ImpedanceModel, omega, *, ts: float | None = None, p_ol=0,
                   labels=None) -> Scenarios:  # fmt: skip
    """Scenarios from plant responses ``P`` (``(S, N, n, n)`` or ``(N, n, n)``) on ``omega``.

    ``model``: the nominal model the controller inverts. ``p_ol``: open-loop RHP poles of
    each plant (int or ``(S,)``); the controller's own (CRHP roots of det Ẑ_H) are added.
    """
    P = np.asarray(P, dtype=complex)
    if P.ndim == 3:
        P = P[None]
    omega = np.asarray(omega, dtype=float)
    if P.ndim != 4 or P.shape[1] != omega.shape[0] or P.shape[2] != P.shape[3]:
        raise ValueError(f"make_scenarios: P must be (S, N, n, n) on omega (N,), got {P.shape}")
    if P.shape[-1] != model.n:
        raise ValueError(
            f"make_scenarios: plants are {P.shape[-1]}×{P.shape[-1]}, model n = {model.n}"
        )
    if not np.all(np.isfinite(P)):
        raise ValueError("make_scenarios: plant responses contain NaN or inf")
    Q = P @ matrix_part(model, omega, ts)[None]
    lam, V = np.linalg.eig(Q)
    Vi = np.linalg.inv(V)
    rec = (V * lam[..., None, :]) @ Vi
    err = float(np.max(np.linalg.norm(rec - Q, axis=(-2, -1)) / np.linalg.norm(Q, axis=(-2, -1))))
    S = P.shape[0]
    pol = np.broadcast_to(np.asarray(p_ol, dtype=float), (S,)) + float(
        controller_unstable_poles(model)
    )
    if labels is not None and len(labels) != S:
        raise ValueError(f"{len(labels)} labels for {S} plants")
    return Scenarios(jnp.asarray(omega), jnp.asarray(lam), jnp.asarray(V), jnp.asarray(Vi),
                     jnp.asarray(pol), err, None if ts is None else float(ts),
                     tuple(labels) if labels is not None else ())  # fmt: skip


def concat(a: Scenarios, b: Scenarios) -> Scenarios:
    """Both batches in one (same grid and ``ts``)."""
    if a.ts != b.ts or a.omega.shape != b.omega.shape or not np.allclose(a.omega, b.omega):
        raise ValueError("concat: scenarios must share omega and ts")
    la = a.labels or tuple(f"a{i}" for i in range(a.n_scenarios))
    lb = b.labels or tuple(f"b{i}" for i in range(b.n_scenarios))
    cat = lambda x, y: jnp.concatenate([x, y])  # noqa: E731
    return Scenarios(a.omega, cat(a.lam, b.lam), cat(a.V, b.V), cat(a.Vi, b.Vi), cat(a.p_ol, b.p_ol),
                     max(a.recon_err, b.recon_err), a.ts, la + lb)  # fmt: skip
