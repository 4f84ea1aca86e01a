# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Posterior-predictive credible bands of impedances and plants (vmapped over samples).

Quantities (each per frequency ω, ``(N, …)``; linear magnitudes, convert to dB yourself):

- ``"abs_Z_H"``, ``"abs_Z_T"`` — element magnitudes ``|Ẑ_ij|`` (``(N, n, n)``);
- ``"sv_Z_H"``, ``"sv_Z_T"`` — singular values, descending (``(N, n)``);
- ``"sv_P"`` — singular values of ``P̂ = Ẑ_H Ẑ_T⁻¹`` (``(N, n)``);
- ``"sv_P_Phatinv"`` — singular values of ``P P̂⁻¹`` with ``P = P_ref`` the measured or true
  plant (``(N, n)``; ``P_ref`` required). Its band around 0 dB is the paper's model-quality
  figure.

Band ``q`` levels are quantiles over the samples, per frequency and per index (singular
values are sorted per sample before the quantile, so the k-th band is the band of the k-th
largest singular value).
"""

from __future__ import annotations

import dataclasses
import enum
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._linalg import svdvals
from .._plain import jsonable
from ..fit._pd import theta_to_model
from ..impedance import plant
from ..samples import PosteriorSamples
from ._model_error import NoError, model_error_for

QUANTITIES = ("abs_Z_H", "abs_Z_T", "sv_Z_H", "sv_Z_T", "sv_P", "sv_P_Phatinv")


class PredictiveQuantities(NamedTuple):
    """Per-sample quantities of the module docstring (:func:`predictive_samples`), each
    ``(S', N, …)`` — ``S'`` samples, ``N`` frequencies — linear magnitudes (N/m for the
    impedances, dimensionless for the plants); ``None`` for a quantity not asked for.

    - ``abs_Z_H``, ``abs_Z_T``: ``(S', N, n, n)``; ``sv_Z_H``, ``sv_Z_T``, ``sv_P``,
      ``sv_P_Phatinv``: ``(S', N, n)``, descending.

    :meth:`computed` gives the computed ones by name.
    """

    abs_Z_H: np.ndarray | None = None
    abs_Z_T: np.ndarray | None = None
    sv_Z_H: np.ndarray | None = None
    sv_Z_T: np.ndarray | None = None
    sv_P: np.ndarray | None = None
    sv_P_Phatinv: np.ndarray | None = None

    def computed(self) -> dict[str, np.ndarray]:
        """``{name: array}`` of the quantities that were computed, in :data:`QUANTITIES`
        order."""
        return {k: v for k, v in self._asdict().items() if v is not None}


class CredibleBands(NamedTuple):
    """Credible bands of the quantities of the module docstring (:func:`credible_bands`):
    ``q`` ``(Q,)`` the quantile levels in [0, 1], and per quantity ``(Q, N, …)`` the
    quantiles over the samples (row ``k`` at level ``q[k]``), shapes and units as in
    :class:`PredictiveQuantities` with ``Q`` for ``S'``; ``None`` for a quantity not asked for.

    :meth:`computed` gives the computed ones by name.
    """

    q: np.ndarray
    abs_Z_H: np.ndarray | None = None
    abs_Z_T: np.ndarray | None = None
    sv_Z_H: np.ndarray | None = None
    sv_Z_T: np.ndarray | None = None
    sv_P: np.ndarray | None = None
    sv_P_Phatinv: np.ndarray | None = None

    def computed(self) -> dict[str, np.ndarray]:
        """``{name: (Q, N, …) array}`` of the quantities that were computed, in
        :data:`QUANTITIES` order."""
        return {k: v for k, v in self._asdict().items() if k != "q" and v is not None}


class PredictivePlants(NamedTuple):
    """Posterior-predictive draws of the true impedances and plant (:func:`predictive_plants`).

    - ``omega``: ``(N,)`` rad/s, the grid.
    - ``Z_H``, ``Z_T``: ``(S', N, n, n)`` complex, N/m, one row per draw.
    - ``P``: ``(S', N, n, n)`` complex, ``Z_H Z_T⁻¹`` per draw (dimensionless).
    """

    omega: np.ndarray
    Z_H: np.ndarray
    Z_T: np.ndarray
    P: np.ndarray


@eqx.filter_jit
def _chunk(theta, scale, s, P_ref, names):
    def one(t):
        m = theta_to_model(t, scale)
        ZH, ZT = m.hand(s), m.total(s)
        out = {}
        if "abs_Z_H" in names:
            out["abs_Z_H"] = jnp.abs(ZH)
        if "abs_Z_T" in names:
            out["abs_Z_T"] = jnp.abs(ZT)
        if "sv_Z_H" in names:
            out["sv_Z_H"] = svdvals(ZH)
        if "sv_Z_T" in names:
            out["sv_Z_T"] = svdvals(ZT)
        if "sv_P" in names:
            out["sv_P"] = svdvals(plant(ZH, ZT))
        if "sv_P_Phatinv" in names:
            # P P̂⁻¹ = P Ẑ_T Ẑ_H⁻¹
            out["sv_P_Phatinv"] = svdvals(plant(P_ref @ ZT, ZH))
        return out

    return jax.vmap(one)(theta)


def predictive_samples(
    ps: PosteriorSamples, omega, quantities=("sv_Z_H", "sv_Z_T", "sv_P"), P_ref=None,
    chunk: int = 500, max_samples: int | None = 2000, seed: int = 0,
) -> PredictiveQuantities:  # fmt: skip
    """Per-sample quantities (:class:`PredictiveQuantities`, each ``(S', N, …)``) on
    ``omega`` (rad/s), computed in chunks.

    At most ``max_samples`` samples are used (a random subset, ``seed``); ``None`` = all.
    """
    names = tuple(quantities)
    bad = [q for q in names if q not in QUANTITIES]
    if bad:
        raise ValueError(f"unknown quantities {bad}; choose from {QUANTITIES}")
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if omega.ndim != 1:
        raise ValueError(f"omega must be (N,), got shape {omega.shape}")
    if "sv_P_Phatinv" in names:
        if P_ref is None:
            raise ValueError("sv_P_Phatinv needs P_ref (N, n, n): the measured or true plant")
        P_ref = jnp.asarray(P_ref, dtype=jnp.complex128)
        if P_ref.shape != (omega.shape[0], ps.n, ps.n):
            raise ValueError(f"P_ref must be ({omega.shape[0]}, {ps.n}, {ps.n}), got {P_ref.shape}")
    else:
        P_ref = jnp.zeros((1, 1, 1), dtype=jnp.complex128)
    theta = ps.theta
    if max_samples is not None and theta.shape[0] > max_samples:
        idx = np.random.default_rng(seed).choice(theta.shape[0], max_samples, replace=False)
        theta = theta[np.sort(idx)]
    s = 1j * omega
    parts = [
        _chunk(jnp.asarray(theta[i : i + chunk]), ps.scale, s, P_ref, names)
        for i in range(0, theta.shape[0], chunk)
    ]
    return PredictiveQuantities(
        **{k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in names}
    )


def credible_bands(
    ps: PosteriorSamples, omega, quantities=("sv_Z_H", "sv_Z_T", "sv_P"), P_ref=None,
    q=(0.05, 0.5, 0.95), chunk: int = 500, max_samples: int | None = 2000, seed: int = 0,
) -> CredibleBands:  # fmt: skip
    """Credible bands (:class:`CredibleBands`, each ``(len(q), N, …)``) of the quantities
    (module docstring) over the posterior samples, on ``omega`` (rad/s). Default levels
    5/50/95 %."""
    qs = np.asarray(q, dtype=float)
    if np.any((qs < 0) | (qs > 1)):
        raise ValueError(f"quantile levels must be in [0, 1], got {q}")
    per = predictive_samples(ps, omega, quantities, P_ref, chunk, max_samples, seed)
    return CredibleBands(qs, **{k: np.quantile(v, qs, axis=0) for k, v in per.computed().items()})


# --- predictive draws of the plant, model error included ------------------------------


def _taper(omega, lo, hi, width: float = 0.5):
    """1 on [lo, hi], raised-cosine to 0 within ``width`` (natural-log units) outside."""
    lw = np.log(omega)
    d = np.maximum(np.log(lo) - lw, 0.0) + np.maximum(lw - np.log(hi), 0.0)
    return np.where(d >= width, 0.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(d / width, 1.0))))


def predictive_plants(ps: PosteriorSamples, omega, *, max_samples: int | None = 500, seed: int = 0,
                      include_error: bool = True, error_band=None,
                      taper_width: float = 0.5) -> PredictivePlants:  # fmt: skip
    """Posterior-predictive draws of the *true* ``Z_H, Z_T, P = Z_H Z_T⁻¹`` on ``omega`` (rad/s,
    any grid), including the model-error term — not only parameter uncertainty.

    Per draw ``(θ, τ, ℓ, β, κ)``: ``Z(θ)`` of the second-order model plus the model-error
    function drawn from its posterior *given that draw's fit residuals* (with ``hyper="map"``,
    the default, the hyperparameters are the same in every draw — their posterior mode — and
    only θ varies; files with six gp columns are read with κ = 0):

    The model-error object of the samples (:func:`~hapid.uncertainty.model_error_for`)
    draws the term (:meth:`~hapid.uncertainty.ModelError.predictive_errors`):

    - :class:`~hapid.uncertainty.GP`: the error functions ``e_H, e_M`` (per element, re and
      im) are the GP of :func:`hapid.uncertainty._gp.gp_covariance`; the draw at ``omega`` is
      the exact GP conditional on the residuals ``[Ẑ_H − Z_H(θ); Ẑ_T − Z_T(θ)]`` at the fit
      frequencies (pathwise: a joint prior draw on fit ∪ new frequencies corrected by
      ``K_{*x} C⁻¹ (r − ỹ)``, Matheron's rule). Far from the fit band it reverts to the prior
      (amplitude ``τ a(ω)``, :func:`~hapid.uncertainty._weights.gp_amplitudes`, with the
      slope factor ``(ω/ω_ref)^β`` held at its band-edge value beyond the fit band).
    - :class:`~hapid.uncertainty.GPCorr`: the same exact conditional for the correlated model
      (shared latent function of ``e_H`` and ``e_M``, complex ρ, asinh knee coordinate:
      :func:`hapid.uncertainty._gp.gp_corr_covariance`), in complex circular form.
    - :class:`~hapid.uncertainty.White`: independent circular errors of variance
      ``τ² a(ω)²`` at each new frequency (``a`` log-log interpolated from the fit band): the
      white model has no correlation to condition on.
    - :class:`~hapid.uncertainty.NoError` (or ``include_error=False``): ``Z(θ)`` only.

    ``error_band = (ω_lo, ω_hi)`` (rad/s, optional) confines the error term to that band: it
    is multiplied by a taper that is 1 inside and falls to 0 (raised cosine) within a factor
    e^taper_width of frequency outside — for loop analyses that need a rational plant far from
    the data (see :func:`hapid.tune._recipe.predictive_scenario_plants`).

    ``Z_T`` carries ``e_H + e_M`` (``Z_T = Z_H + Z_M``). Returns :class:`PredictivePlants`
    ``(omega (N,), Z_H, Z_T, P (S', N, n, n))`` with at most ``max_samples`` draws (random
    subset, ``seed``).
    """
    omega = np.asarray(omega, dtype=np.float64)
    if (
        omega.ndim != 1
        or omega.shape[0] < 1
        or not np.all(np.isfinite(omega))
        or np.any(omega <= 0)
    ):
        raise ValueError(
            "predictive_plants: omega must be a 1-D array of positive frequencies (rad/s)"
        )
    rng = np.random.default_rng(seed)
    S = ps.n_samples
    idx = np.arange(S)
    if max_samples is not None and S > max_samples:
        idx = np.sort(rng.choice(S, max_samples, replace=False))
    theta = ps.theta[idx]
    error = model_error_for(ps) if include_error else NoError()
    data = ps.predictive
    if not isinstance(error, NoError) and data is None:
        raise ValueError("predictive_plants: these samples carry no fit data (old file or Laplace-NLS "
                         "draws); rerun hapid posterior, or pass include_error=False")  # fmt: skip
    ms = jax.vmap(lambda t: theta_to_model(t, ps.scale))(jnp.asarray(theta))
    s_new = 1j * jnp.asarray(omega)
    ZH = np.asarray(jax.vmap(lambda m: m.hand(s_new))(ms))
    ZM = np.asarray(jax.vmap(lambda m: m.mechanism(s_new))(ms))
    w = None if error_band is None else _taper(omega, *error_band, taper_width)
    eH, eM = error.predictive_errors(ps, idx, ms, omega, rng, w)
    ZH, ZM = ZH + eH, ZM + eM
    ZT = ZH + ZM
    return PredictivePlants(omega, ZH, ZT, np.asarray(plant(ZH, ZT)))


#: default slack of :func:`band_calibration`'s goal: the band is calibrated when its coverage
#: is at least ``level − COVERAGE_SLACK`` (a calibrated band's coverage over a few hundred
#: frequencies scatters by about ±0.03 around ``level``)
COVERAGE_SLACK = 0.05


class CalibrationStatus(enum.StrEnum):
    """Verdict of a :class:`BandCalibration`: ``calibrated`` when the coverage reaches the
    goal, ``overconfident`` when the band holds the truth less often (too narrow or off
    centre)."""

    CALIBRATED = "calibrated"
    OVERCONFIDENT = "overconfident"


@dataclasses.dataclass(frozen=True)
class BandCalibration:
    """How well predictive draws describe a true response (:func:`band_calibration`, which
    defines the figures): ``coverage``, ``width_ratio``, ``width_ratio_calibrated``,
    ``coverage_calibrated``, ``width_ratio_of_medians``, ``element_coverage``,
    ``rel_error_median``, ``rel_radius_median`` (floats, fractions or ratios); ``level`` the
    credible level of the band and ``goal`` the coverage that counts as calibrated.

    ``status`` (:class:`CalibrationStatus`): ``calibrated`` when ``coverage ≥ goal``, else
    ``overconfident``; ``ok`` when calibrated.
    """

    coverage: float
    width_ratio: float
    width_ratio_calibrated: float
    coverage_calibrated: float
    width_ratio_of_medians: float
    element_coverage: float
    rel_error_median: float
    rel_radius_median: float
    level: float
    goal: float

    @property
    def status(self) -> CalibrationStatus:
        if self.coverage >= self.goal:
            return CalibrationStatus.CALIBRATED
        return CalibrationStatus.OVERCONFIDENT

    @property
    def ok(self) -> bool:
        return self.status is CalibrationStatus.CALIBRATED

    def figures(self) -> dict[str, float]:
        """The eight figures by name (Python floats, NaN kept), without ``level`` and
        ``goal``: a row of a calibration table."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name not in ("level", "goal")}  # fmt: skip

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``level``, ``goal``, then :meth:`figures`
        (a non-finite figure is ``None``)."""
        return jsonable({"status": self.status, "ok": self.ok, "level": self.level,
                         "goal": self.goal, **self.figures()})  # fmt: skip


def credible_ball(draws, level: float):
    """The ``level`` credible ball of draws ``(S, N, n, n)`` (complex) per frequency:
    ``(median (N, n, n), distances (S, N), radius (N,))`` — the elementwise re/im median, each
    draw's Frobenius distance from it and their ``level`` quantile (the ball of
    :func:`band_calibration` and :func:`~hapid.uncertainty.holdout_check`)."""
    X = np.asarray(draws)
    med = np.median(X.real, 0) + 1j * np.median(X.imag, 0)
    d = np.linalg.norm(X - med[None], axis=(-2, -1))
    return med, d, np.quantile(d, level, axis=0)


def band_calibration(draws, truth, level: float = 0.9, n_reference: int = 20,
                     goal: float | None = None) -> BandCalibration:  # fmt: skip
    """How well predictive draws ``(S, N, n, n)`` (complex) describe a true response
    ``(N, n, n)`` over ``N`` frequencies: a :class:`BandCalibration`, ``calibrated`` when
    ``coverage ≥ goal`` (default ``level −`` :data:`COVERAGE_SLACK`, at least 0). Raises
    ``ValueError`` for mismatched shapes or a ``level`` or ``goal`` outside [0, 1].

    The band at frequency ω is the ``level`` credible *ball* around the draws' (elementwise
    re/im) median ``X̃``: radius ``r(ω) = q_level(‖X_s − X̃‖_F)``; the actual error is
    ``e(ω) = ‖X_true − X̃‖_F`` (Frobenius norm of the complex matrix, i.e. the Euclidean norm
    of its ``2n²`` real numbers).

    - ``coverage`` — fraction of frequencies with ``e ≤ r`` (nominal: ``level``);
    - ``width_ratio`` — median over frequencies of ``r(ω)/e(ω)``: the band's *half*-width (its
      radius) in units of the actual error at the same frequency (scale-free, so frequencies
      where P is large do not dominate). A perfectly calibrated Gaussian band gives
      ``q_level(χ_m)/q_50(χ_m)`` for ``m`` real dimensions of equal spread — 2.44 (m = 1),
      1.82 (a circular complex scalar), 1.22 (3 × 3 complex), 1.13 (5 × 5) — and a value
      between these for an elongated band;
    - ``width_ratio_calibrated``, ``coverage_calibrated`` — the same two numbers with the
      truth replaced by one of the draws (mean over ``n_reference`` of them): what *this* band
      would give if it were exactly calibrated, the yardstick for ``width_ratio``;
    - ``width_ratio_of_medians`` — ``median_ω r / median_ω e`` (the earlier definition);
    - ``element_coverage`` — fraction of (frequency, element, re/im) whose central ``level``
      interval holds the truth;
    - ``rel_error_median`` — median of ``e / ‖X_true‖_F``; ``rel_radius_median`` — median of
      ``r / ‖X_true‖_F`` (the band's half-width relative to the response itself: a band can
      meet ``width_ratio`` by being centred badly, this says how wide it is in absolute terms).
    """
    goal = max(level - COVERAGE_SLACK, 0.0) if goal is None else float(goal)
    if not (0.0 <= level <= 1.0 and 0.0 <= goal <= 1.0):
        raise ValueError(f"band_calibration: level and goal must be in [0, 1], got {level}, {goal}")
    X = np.asarray(draws)
    T = np.asarray(truth)
    if X.ndim != 4 or T.shape != X.shape[1:]:
        raise ValueError(
            f"band_calibration: draws (S, N, n, n) and truth (N, n, n), got {X.shape}, {T.shape}"
        )
    med, d, r = credible_ball(X, level)
    e = np.linalg.norm(T - med, axis=(-2, -1))
    tiny = 1e-300
    ref = d[: max(1, min(n_reference, X.shape[0]))]  # draws standing in for the truth
    lo_q, hi_q = (1 - level) / 2, 1 - (1 - level) / 2
    inside = []
    for part in (np.real, np.imag):
        lo, hi = np.quantile(part(X), [lo_q, hi_q], axis=0)
        inside.append((part(T) >= lo) & (part(T) <= hi))
    return BandCalibration(
        coverage=float(np.mean(e <= r)),
        width_ratio=float(np.median(r / np.maximum(e, tiny))),
        width_ratio_calibrated=float(np.mean(np.median(r / np.maximum(ref, tiny), axis=1))),
        coverage_calibrated=float(np.mean(ref <= r)),
        width_ratio_of_medians=float(np.median(r) / np.median(e)),
        element_coverage=float(np.mean(inside)),
        rel_error_median=float(np.median(e / np.linalg.norm(T, axis=(-2, -1)))),
        rel_radius_median=float(np.median(r / np.linalg.norm(T, axis=(-2, -1)))),
        level=float(level),
        goal=goal,
    )
