"""Draws of the true plant ``P`` on any grid from a posterior-samples file, by either
construction (``hapid predict --draws``): :func:`plant_draws` → :class:`PlantDraws`.

- ``"params"``: the posterior's parameter draws plus their model-error term
  (:func:`hapid.uncertainty.predictive_plants`): ``P``, ``Z_H`` and ``Z_T`` per draw.
- ``"loop_gp"``: ``P_d = Q_d P̂`` with ``Q_d`` drawn from the GP of the loop coordinate
  conditioned on the whole measured FRF the file stores (:func:`fit_loop_gp`,
  :func:`loop_gp_plants`); ``P̂`` the NLS fit the posterior was built around. ``P`` only:
  the loop coordinate does not split into ``Z_H`` and ``Z_T``.
"""

from __future__ import annotations

import dataclasses
import enum

import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from .._plain import jsonable
from ..fit._pd import theta_to_model
from ..samples import PosteriorSamples
from ._draws import ParamDraws, draws_from
from ._predictive import predictive_plants


class DrawsStatus(enum.StrEnum):
    """Outcome of :func:`plant_draws` (:class:`PlantDraws`); ``ok`` means ``OK``."""

    OK = "ok"
    NON_FINITE = "non-finite draws"


@dataclasses.dataclass(frozen=True)
class PlantDraws:
    """Draws of the true plant on ``omega (N,)`` rad/s.

    - ``P``: ``(S, N, n, n)`` complex; ``Z_H``, ``Z_T``: the same shape for ``"params"``
      draws, ``None`` for ``"loop_gp"``.
    - ``draws``: ``"loop_gp"`` or ``"params"``; ``model_error``: the params draws' model-error
      kind (``"none"``, ``"white"``, ``"gp"``, ``"gp_corr"``), ``"loop_gp"`` for loop draws.
    - ``info``: for ``"loop_gp"`` the GP's ``ell``, ``eta``, ``sigma2`` and the measured band
      ``measured_hz`` ``[f₁, f_e]`` (Hz; above ``f_e`` each draw tapers to the model's own
      plant); empty for ``"params"``.
    """

    omega: np.ndarray
    P: np.ndarray
    Z_H: np.ndarray | None
    Z_T: np.ndarray | None
    draws: str
    model_error: str
    info: dict = dataclasses.field(default_factory=dict)

    @property
    def nonfinite_draws(self) -> int:
        """The draws with a non-finite value in any of :attr:`arrays`."""
        finite = [np.all(np.isfinite(a), axis=(1, 2, 3)) for a in self.arrays.values()]
        return int(np.sum(~np.logical_and.reduce(finite)))

    @property
    def ok(self) -> bool:
        """Every draw finite."""
        return self.nonfinite_draws == 0

    @property
    def status(self) -> DrawsStatus:
        """:class:`DrawsStatus`: ``OK`` (:attr:`ok`) or ``NON_FINITE``."""
        return DrawsStatus.OK if self.ok else DrawsStatus.NON_FINITE

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """The draws that exist: ``{"P"}`` (loop_gp) or ``{"P", "Z_H", "Z_T"}`` (params)."""
        names = ("P", "Z_H", "Z_T")
        return {k: getattr(self, k) for k in names if getattr(self, k) is not None}

    def summary(self) -> dict:
        """Strict-JSON summary: status, family, draw count, grid (Hz), ``info``."""
        f = np.asarray(self.omega) / TWO_PI
        return jsonable({"status": self.status, "ok": self.ok, "draws": self.draws,
                "model_error": self.model_error, "n_draws": int(self.P.shape[0]),
                "n_freq": int(f.size), "f_min_hz": float(f[0]), "f_max_hz": float(f[-1]),
                "quantities": list(self.arrays), **self.info})  # fmt: skip


def nominal_model(ps: PosteriorSamples):
    """The model the posterior was built around: the NLS fit ``hapid posterior`` records
    (``diagnostics["fit_theta"]``), else the component-wise median of the θ draws (folded:
    non-negative factor diagonals, so a valid model)."""
    th = ps.diagnostics.get("fit_theta")
    th = np.median(ps.theta, axis=0) if th is None else np.asarray(th, dtype=float)
    if th.shape != (ps.n_theta,):
        raise ValueError(f"the samples' fit_theta has shape {th.shape}, expected ({ps.n_theta},)")
    return theta_to_model(jnp.asarray(th), ps.scale)


def plant_draws(
    ps: PosteriorSamples,
    omega,
    *,
    draws: str = "auto",
    max_samples: int = 500,
    seed: int = 0,
    include_error: bool = True,
) -> PlantDraws:
    """Draws of the true ``P`` on ``omega (N,)`` rad/s (module docstring).

    ``draws``: ``"auto"`` (``"loop_gp"`` when ``ps.measured`` holds the measured FRF and
    ``include_error`` is true, else ``"params"``), ``"loop_gp"`` or ``"params"``.
    ``max_samples``: ``"params"``: at most that many posterior draws (random subset, ``seed``);
    ``"loop_gp"``: exactly that many loop draws (``seed``). ``include_error=False`` (parameter
    uncertainty only) applies to ``"params"``.

    Raises ``ValueError`` for an unknown ``draws``, ``"loop_gp"`` without a measured FRF or
    with ``include_error=False``, ``max_samples < 1`` or a bad ``omega``.
    """
    omega = np.asarray(omega, dtype=np.float64)
    if omega.ndim != 1 or omega.size < 1 or not np.all(np.isfinite(omega)) or np.any(omega <= 0):
        raise ValueError("plant_draws: omega must be a 1-D array of positive frequencies (rad/s)")
    if int(max_samples) < 1:
        raise ValueError(f"plant_draws: max_samples must be ≥ 1, got {max_samples}")
    if draws == "auto" and not include_error:
        draws = "params"  # parameter uncertainty only was asked for
    source = draws_from(draws, samples=ps, measured=ps.measured, model_error=include_error)
    if isinstance(source, ParamDraws):
        d = predictive_plants(ps, omega, max_samples=int(max_samples), seed=seed,
                              include_error=include_error)  # fmt: skip
        return PlantDraws(omega, d.P, d.Z_H, d.Z_T, "params",
                          ps.error_kind if include_error else "none")  # fmt: skip
    if not include_error:
        raise ValueError("loop draws are of the measured plant (no separate model error): "
                         "leave out include_error=False / --no-model-error, or use params draws")  # fmt: skip
    model = nominal_model(ps)
    gp = source.gp(model)
    P = source.plants(model, omega, int(max_samples), seed, gp=gp)
    info = {"ell": float(gp.ell), "eta": float(gp.eta), "sigma2": float(gp.sigma2),
            "measured_hz": list(source.band_hz())}  # fmt: skip
    return PlantDraws(omega, P, None, None, "loop_gp", "loop_gp", info)
