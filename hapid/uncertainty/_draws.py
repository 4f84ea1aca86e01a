"""The two constructions of draws of the true plant, as objects: one interface for
``hapid predict``, ``hapid robust`` and the tuner.

- :class:`ParamDraws` — the posterior's parameter draws of the second-order model (a samples
  file), with their model-error term (``model_error=True``) or without.
- :class:`LoopDraws` — draws of the loop coordinate ``Q = P P̂⁻¹`` conditioned on a measured
  FRF (:func:`hapid.uncertainty.measured_loop_gp`), around a model ``P̂``.

Both have ``name`` (``"params"`` / ``"loop_gp"``, the CLI's ``--draws``) and
``plants(model, omega, n_draws, seed) -> (S, N, n, n)`` complex ``P`` on ``omega`` (rad/s).
:func:`draws_from` is the one map from the CLI's ``--draws auto|loop_gp|params`` to an object.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..defaults import DRAWS
from ..samples import PosteriorSamples
from ._loopgp import LoopGP, loop_gp_plants, measured_data, measured_loop_gp
from ._model_error import NoError, model_error_for
from ._predictive import predictive_plants


@dataclasses.dataclass(frozen=True)
class ParamDraws:
    """Posterior parameter draws (``samples``) of the second-order model; with
    ``model_error`` each draw also carries its model-error term (posterior-predictive
    plants, :func:`hapid.uncertainty.predictive_plants`, samples that have one)."""

    samples: PosteriorSamples
    model_error: bool = False
    name = "params"

    def __post_init__(self):
        if not isinstance(self.samples, PosteriorSamples):
            raise TypeError(f"ParamDraws: samples must be PosteriorSamples, got "
                            f"{type(self.samples).__name__}")  # fmt: skip

    @property
    def has_error_term(self) -> bool:
        """``model_error`` asked for and the samples have a model-error term and its data."""
        s = self.samples
        has_term = not isinstance(model_error_for(s), NoError)
        return self.model_error and has_term and s.predictive is not None

    def plants(self, model, omega, n_draws: int, seed: int = 0) -> np.ndarray:
        """``P`` of at most ``n_draws`` posterior draws (random subset, ``seed``) on
        ``omega (N,)`` rad/s: ``(S, N, n, n)`` complex. ``model`` is not used (the draws are
        their own models)."""
        d = predictive_plants(self.samples, np.asarray(omega, dtype=float), max_samples=int(n_draws),
                              seed=seed, include_error=self.model_error)  # fmt: skip
        return d.P


@dataclasses.dataclass(frozen=True)
class LoopDraws:
    """Draws of ``Q = P P̂⁻¹`` conditioned on the measured FRF ``measured`` (an
    :class:`~hapid.frf.FRF` or a dict with ``omega, Z_H, Z_T`` and optionally their std)."""

    measured: object
    name = "loop_gp"

    def __post_init__(self):
        if self.measured is None:
            raise ValueError("loop draws need the measured FRF: give an FRF file, or a samples "
                             "file written by hapid posterior (it stores the FRF)")  # fmt: skip

    def gp(self, model) -> LoopGP:
        """The GP of ``Q − I`` around ``model``, hyperparameters by leave-one-out."""
        return measured_loop_gp(measured_data(self.measured), model)

    def band_hz(self) -> tuple[float, float]:
        """The measured band ``(f₁, f_e)`` in Hz (above ``f_e`` each draw tapers to the
        model's own plant)."""
        om = measured_data(self.measured)["omega"]
        return float(om[0] / (2 * np.pi)), float(om[-1] / (2 * np.pi))

    def plants(self, model, omega, n_draws: int, seed: int = 0, *, gp: LoopGP | None = None):
        """``P_d = Q_d P̂`` for ``n_draws`` draws on ``omega (N,)`` rad/s: ``(S, N, n, n)``
        complex (``gp``: a GP already fitted around ``model``)."""
        gp = self.gp(model) if gp is None else gp
        return loop_gp_plants(gp, model, np.asarray(omega, dtype=float), int(n_draws), seed)


Draws = ParamDraws | LoopDraws


def draws_from(name: str, *, samples=None, measured=None, model_error: bool = True) -> Draws:
    """The draws the CLI's ``--draws`` names: ``"auto"`` is loop draws when a measured FRF
    (``measured``) is known, else the samples' parameter draws; ``"loop_gp"`` needs
    ``measured``, ``"params"`` needs ``samples``. Raises ``ValueError`` naming what is
    missing or the allowed names."""
    if name not in DRAWS:
        raise ValueError(f"draws must be one of {DRAWS}, got {name!r}")
    kind = name if name != "auto" else ("loop_gp" if measured is not None else "params")
    if kind == "loop_gp":
        return LoopDraws(measured)
    if samples is None:
        raise ValueError("parameter draws need a posterior-samples file (hapid posterior)")
    return ParamDraws(samples, model_error=model_error)
