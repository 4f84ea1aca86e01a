# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The :class:`PosteriorSamples` value object (posterior draws of the impedance model; files:
:func:`hapid.io.save_samples`, :func:`hapid.io.load_samples`); exported by :mod:`hapid.uncertainty`."""

from __future__ import annotations

import dataclasses
import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import _config  # noqa: F401  (float64)
from ._plain import jsonable
from .fit._pd import Scale, n_params, theta_to_model
from .impedance import ImpedanceModel


class SamplesStatus(enum.StrEnum):
    """Outcome of a posterior sampler (:class:`PosteriorSamples`); ``ok`` means ``CONVERGED``."""

    CONVERGED = "converged"
    NOT_CONVERGED = "not converged"


@dataclasses.dataclass(frozen=True)
class PosteriorSamples:
    """Posterior draws of the PD-parameterized model.

    - ``samples``: ``(S, d)`` — folded θ (``d ≥ p = 6·n(n+1)/2``, diagonals ≥ 0, in ``scale``
      units) followed by any model-error coordinates (``log_tau_H``, ``log_tau_M``, and for
      the GP model error ``log_ell_H``, ``log_ell_M``, ``beta_H``, ``beta_M``).
    - ``predictive``: the fit data the model-error term is conditioned on
      (:meth:`LogPosterior.predictive_data`), or None (Laplace-NLS draws, old files).
    - ``measured``: the whole measured FRF the posterior was built from (``omega (K,)``
      rad/s, ``Z_H``, ``Z_T (K, n, n)``: every measured frequency, also above the fit band),
      or None. The robust check and the tuner draw the loop from it
      (:func:`hapid.robust.loop_gp_check`).
    - ``log_prob``: ``(S,)`` log-posterior of each draw (NaN for Laplace draws).
    - ``scale``: the :class:`~hapid.fit.Scale` θ is expressed in.
    - ``n``: rods. ``names``: the ``d`` coordinate names.
    - ``diagnostics``: method, acceptance fraction, τ per parameter, ESS, steps, timings …
    """

    samples: np.ndarray
    log_prob: np.ndarray
    scale: Scale
    n: int
    names: tuple[str, ...]
    diagnostics: dict = dataclasses.field(default_factory=dict)
    predictive: dict | None = None  # LogPosterior.predictive_data(): fit data for predictions
    measured: dict | None = None  # the whole measured FRF: omega, Z_H, Z_T

    def __post_init__(self):
        s = np.asarray(self.samples)
        p = n_params(self.n)
        if s.ndim != 2 or s.shape[1] not in (p, p + 2, p + 6, p + 8, p + 10):
            raise ValueError(
                f"PosteriorSamples: samples must be (S, {p}) or (S, {p}+model-error) for n = "
                f"{self.n}, got shape {s.shape}"
            )
        if np.shape(self.log_prob) != (s.shape[0],):
            raise ValueError("PosteriorSamples: log_prob must be (S,)")
        if len(self.names) != s.shape[1]:
            raise ValueError("PosteriorSamples: names must match the number of columns")

    @property
    def n_samples(self) -> int:
        return int(self.samples.shape[0])

    @property
    def n_theta(self) -> int:
        return n_params(self.n)

    @property
    def theta(self) -> np.ndarray:
        """``(S, p)`` folded θ (canonical factors, non-negative diagonals)."""
        return self.samples[:, : self.n_theta]

    @property
    def tau(self) -> np.ndarray | None:
        """``(S, 2)`` relative model-error scales τ_H, τ_M (None without model error)."""
        extra = self.samples[:, self.n_theta : self.n_theta + 2]
        return np.exp(extra) if extra.shape[1] else None

    @property
    def ell(self) -> np.ndarray | None:
        """``(S, 2)`` GP length scales ℓ_H, ℓ_M (log-frequency units; None unless gp)."""
        extra = self.samples[:, self.n_theta + 2 : self.n_theta + 4]
        return np.exp(extra) if extra.shape[1] else None

    @property
    def error_kind(self) -> str:
        """``"none"``, ``"white"``, ``"gp"`` or ``"gp_corr"`` (from the number of model-error
        columns: 0, 2, 6 or 8, 10)."""
        k = self.samples.shape[1] - self.n_theta
        return {0: "none", 2: "white", 6: "gp", 8: "gp", 10: "gp_corr"}[k]

    def models(self, idx=None) -> ImpedanceModel:
        """Batched :class:`ImpedanceModel` (arrays ``(S, n, n)``; physical units)."""
        th = jnp.asarray(self.theta if idx is None else self.theta[idx])
        return _models(th, self.scale)

    def physical(self) -> dict[str, np.ndarray]:
        """``{"M_H": (S, n, n), …, "K_M": …}`` physical matrices of every draw."""
        m = self.models()
        h, mech = m.hand, m.mechanism
        vals = (h.M, h.B, h.K, mech.M, mech.B, mech.K)
        return {
            k: np.asarray(v)
            for k, v in zip(("M_H", "B_H", "K_H", "M_M", "B_M", "K_M"), vals, strict=True)
        }

    @property
    def ok(self) -> bool:
        """Every draw finite, and the sampler's own convergence check passed where it made one
        (emcee: chain ≥ 50 τ; Laplace: the mode search converged)."""
        d = self.diagnostics
        lap = d.get("laplace") if isinstance(d.get("laplace"), dict) else {}
        conv = d.get("converged_50tau", lap.get("converged", d.get("converged", True)))
        return bool(np.all(np.isfinite(np.asarray(self.samples)))) and bool(conv)

    @property
    def status(self) -> SamplesStatus:
        """:class:`SamplesStatus`: ``CONVERGED`` (:attr:`ok`) or ``NOT_CONVERGED``."""
        return SamplesStatus.CONVERGED if self.ok else SamplesStatus.NOT_CONVERGED

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``method``, ``n_samples``, ``d`` (columns),
        ``n``, ``error_kind`` and the sampler's scalar diagnostics (acceptance fraction, τ,
        ESS …) that are present; non-finite numbers as ``None``."""
        d = self.diagnostics
        out = {"status": self.status, "ok": self.ok, "method": d.get("method"),
               "n_samples": self.n_samples, "d": int(self.samples.shape[1]), "n": int(self.n),
               "error_kind": self.error_kind}  # fmt: skip
        out |= {k: d[k] for k in _REPORTED if d.get(k) is not None}
        return jsonable(out)

    def report(self) -> str:
        """One line: method, sample count, dimension and the sampler's diagnostics."""
        d = self.diagnostics
        parts = [f"{d.get('method', '?')}: {self.n_samples} samples, d = {self.samples.shape[1]}"]
        for k in _REPORTED:
            if k in d and d[k] is not None:
                parts.append(f"{k} {d[k]:.4g}")
        return "; ".join(parts)


_REPORTED = ("acceptance_fraction", "tau_max", "steps_over_tau", "ess_min", "ess_per_s")


@eqx.filter_jit
def _models(theta, scale):
    return jax.vmap(lambda t: theta_to_model(t, scale))(theta)
