# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""The value object returned by :func:`hapid.fit.fit_nls`."""

from __future__ import annotations

import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._plain import enum_members, jsonable
from ..impedance import ImpedanceModel, SecondOrder
from ._pd import MATRIX_NAMES, Scale, boundary_names, theta_to_model


class FitStatus(enum.StrEnum):
    """Outcome of a fit: the status of :class:`NLSResult`, :class:`~hapid.fit.MLResult`,
    :class:`~hapid.fit.ImpedanceFit` and :class:`hapid.pipeline.Fit`. The value is the word
    the CLI and the model files use. ``ok`` means ``CLOSED_FORM`` or ``CONVERGED``."""

    CLOSED_FORM = "closed form"
    CONVERGED = "converged"
    MAX_STEPS = "max_steps"
    FAILED = "failed"


FIT_OK = (FitStatus.CLOSED_FORM, FitStatus.CONVERGED)
STATUS_NAMES = ("converged", "max_steps", "failed")  # by status_code
CONVERGED, MAX_STEPS, FAILED = 0, 1, 2


class FitFailedError(RuntimeError):
    """Raised by :meth:`NLSResult.raise_if_failed` for a fit that did not converge."""


class NLSResult(eqx.Module):
    """Outcome of a nonlinear PD-constrained fit (single, or a batch under ``vmap``).

    Fields:
    - ``model``: the fitted :class:`ImpedanceModel` (kg, N·s/m, N/m); hand and mechanism PSD.
    - ``theta``: ``(p,)`` unconstrained parameters (``p = 6·n(n+1)/2``) in ``scale`` units
      (see ``hapid.fit._pd``).
    - ``scale``: the :class:`Scale` (ω_ref rad/s, z_ref N/m) that ``theta`` is expressed in.
    - ``status_code``: 0 converged, 1 max_steps, 2 failed (solver failure or non-finite
      result); ``status`` gives the name. A non-converged fit has ``ok`` false.
    - ``n_steps``: solver steps taken.
    - ``cost``: final ``½‖r‖²`` of the weighted residual as optimized (see ``fit_nls``).
    - ``covariance``: ``(p, p)`` Laplace / Gauss–Newton covariance ``σ̂²(JᵀJ)⁺`` of ``theta``
      with ``σ̂² = 2·cost/(m − p)`` (relative, paper, blend weights: the residual scale is
      estimated) or ``σ̂² = 1`` (noise weights: residuals are already in units of their std).
      ``(JᵀJ)⁺`` is a pseudo-inverse (eigenvalues below 1e-12·max dropped).
    - ``sigma2``: the σ̂² used; ``n_residuals``: m (real residuals in the band).
    - ``at_boundary``: ``(6,)`` bool, a fitted ``M_H, B_H, K_H, M_M, B_M, K_M`` has an
      eigenvalue at the PSD boundary (≈ 0 relative to its largest).
    - ``weight``: the weight used; ``solver``: the solver's label, its name in
      :data:`~hapid.fit.SOLVERS` (else its class name) (static).
    """

    model: ImpedanceModel
    theta: Float[Array, "... p"]
    scale: Scale
    status_code: Int[Array, ...]
    n_steps: Int[Array, ...]
    cost: Float[Array, ...]
    covariance: Float[Array, "... p p"]
    sigma2: Float[Array, ...]
    n_residuals: Int[Array, ...]
    at_boundary: Bool[Array, "... 6"]
    weight: str = eqx.field(static=True)
    solver: str = eqx.field(static=True)

    @property
    def status(self):
        """:class:`FitStatus` ``CONVERGED``, ``MAX_STEPS`` or ``FAILED`` (an object array of
        them for a batch). Not under ``jit`` (use ``status_code``)."""
        return enum_members(np.asarray(STATUS_NAMES)[np.asarray(self.status_code)], FitStatus)

    @property
    def ok(self):
        """True when the fit converged (bool array for a batch; works under ``jit``)."""
        return self.status_code == CONVERGED

    @property
    def std(self) -> Float[Array, "... p"]:
        """Laplace standard deviations of ``theta`` (``sqrt(diag(covariance))``)."""
        return jnp.sqrt(jnp.diagonal(self.covariance, axis1=-2, axis2=-1))

    @property
    def boundary(self) -> list[str]:
        """Names of the matrices with an eigenvalue at the PSD boundary (unbatched result)."""
        return boundary_names(self.at_boundary)

    def raise_if_failed(self) -> NLSResult:
        """Raise :class:`FitFailedError` unless every fit converged; returns ``self``."""
        codes = np.atleast_1d(np.asarray(self.status_code))
        if np.any(codes != CONVERGED):
            bad = np.flatnonzero(codes != CONVERGED)
            names = np.asarray(STATUS_NAMES)[codes[bad]]
            where = "" if np.ndim(self.status_code) == 0 else f" (batch indices {bad.tolist()})"
            raise FitFailedError(
                f"NLS fit ({self.solver}, {self.weight} weights) did not converge: "
                f"status {sorted(set(names.tolist()))}{where}, steps {np.asarray(self.n_steps)}, "
                f"cost {np.asarray(self.cost)}"
            )
        return self

    def model_std(self) -> ImpedanceModel:
        """Laplace standard deviations of every entry of M, B, K of ``hand`` and ``total``.

        Delta method through ``theta → model``; returns an :class:`ImpedanceModel` whose
        arrays hold standard deviations (kg, N·s/m, N/m). Unbatched results only (``vmap``
        it for a batch).
        """
        n = self.model.n

        def flat(theta):
            m = theta_to_model(theta, self.scale)
            return jnp.stack([m.hand.M, m.hand.B, m.hand.K, m.total.M, m.total.B, m.total.K])

        G = jax.jacfwd(flat)(self.theta).reshape(6 * n * n, -1)
        var = jnp.einsum("ip,pq,iq->i", G, self.covariance, G)
        sd = jnp.sqrt(jnp.maximum(var, 0.0)).reshape(6, n, n)
        return ImpedanceModel(
            hand=SecondOrder(sd[0], sd[1], sd[2]), total=SecondOrder(sd[3], sd[4], sd[5])
        )

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``solver``, ``weight``, ``n_steps``, ``cost``,
        ``sigma2``, ``n_residuals``, ``boundary`` (matrix names); lists for a batch,
        non-finite numbers as ``None``."""
        batched = np.ndim(self.status_code) > 0
        st = self.status
        return jsonable({
            "status": st.tolist() if batched else st,
            "ok": np.asarray(self.ok), "solver": self.solver, "weight": self.weight,
            "n_steps": np.asarray(self.n_steps), "cost": np.asarray(self.cost),
            "sigma2": np.asarray(self.sigma2), "n_residuals": np.asarray(self.n_residuals),
            "boundary": None if batched else self.boundary,
        })  # fmt: skip

    def report(self) -> str:
        """One line: solver, weights, status, steps, cost, boundary flags (unbatched)."""
        b = self.boundary
        return (
            f"{self.solver} ({self.weight} weights): {self.status} after "
            f"{int(self.n_steps)} steps, cost {float(self.cost):.4g}"
            + (f"; at PSD boundary: {', '.join(b)}" if b else "")
        )


__all__ = ["NLSResult", "FitFailedError", "FitStatus", "FIT_OK", "STATUS_NAMES", "MATRIX_NAMES"]
