"""Evidence-limited design: what a measured FRF certifies about a loop, and the small-gain
condition beyond its highest frequency.

**The principle.** A design is tuned on models (posterior draws of a second-order fit) but
must hold on the true plant. The data say something about the true plant only where they
were measured: the FRF frequencies ``ω_1 … ω_e`` (the *evidence band*; on the paper's
protocol 1–100 Hz, of which the fit uses 1–40 Hz). The design is therefore asked for two
things:

1. **In the evidence band**, the loop on the *measured* plant ``L_meas = P_meas G``
   (``G = g Ẑ_T Ẑ_H⁻¹`` the continuous inverse-model controller) keeps its characteristic loci
   out of the disc of radius ``1/M_s`` around −1 (the tuner's ``frf`` family), and the
   return difference ``σ̲(I + L_meas)`` is reported (:func:`frf_return_difference`).
2. **Beyond the evidence** (``ω ≥ ω_e``) the loop is *small-gain*:
   ``σ̄(L(jω)) ≤ |g(jω)| · σ̄(P P̂⁻¹) ≤ |g(jω)| · m ≤ κ`` with ``m`` a bound on the plant/model
   mismatch ``σ̄(P P̂⁻¹)`` there (default: its largest measured value in the top half-octave of
   the evidence, :func:`mismatch_bound` — an *assumption*, stated as such: above the data no
   method can know the plant) and ``κ = 1/2`` (:data:`KAPPA`).

**Why 2 makes the Nyquist count a property of the data.** For any two plants ``P_a, P_b``
with ``σ̄(P_x G) ≤ κ < 1`` on ``ω ≥ ω_e`` (the true plant and any draw, both within the
mismatch bound), the homotopy ``L_t = (1 − t) P_a G + t P_b G`` has ``σ̄(L_t) ≤ κ`` (σ̄ is a
norm, so the bound is convex), hence ``det(I + L_t) ≠ 0`` there for every ``t`` and the phase
that ``det(I + L)`` collects along ``ω ≥ ω_e`` is the same for both plants (every eigenvalue
``λ`` of ``L_t`` has ``|λ| ≤ κ``, so ``1 + λ`` stays in the disc of radius κ around 1 and
cannot wind around 0). Whatever the plant does above the data — a delay, an extra mode —
cannot change the closed loop's RHP-pole count; the count and the margins are decided
within the band, where the measured FRF constrains the loop. The same bound gives
``|1 + λ| ≥ 1 − κ`` there: a locus crossing the negative real axis above ``ω_e`` has
``GM ≥ 1/κ`` (6 dB for κ = 1/2). This is what the earlier predictive-draw tuning lacked:
above the 40 Hz fit band its draws were bare second-order models and it raised the loop gain
where the true plant's delay and extra mode act (unstable true plant, see
:func:`hapid.tune.robust_design`).

Condition 2 bounds ``|g|`` only, so in the tuner it is a constraint on ``g`` alone
(:func:`small_gain_constraint`), on a log grid from ``ω_e`` up (:func:`beyond_grid`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .. import (
    _config,  # noqa: F401  (float64)
    pipeline,
)
from .._constants import KAPPA  # noqa: F401  (re-exported: σ̄(L) ≤ κ beyond the evidence)
from .._grids import continuous_grid
from .._plain import jsonable
from ..control import Compensator
from ..impedance import plant
from ..pipeline import controller as make_controller
from ..uncertainty._loopgp import measured_data, measured_plant
from ..verdict import Verdict
from ._response import g_response

TOP_BAND = 2.0**-0.5  # the mismatch bound is read over [ω_e / √2, ω_e] (top half-octave)
BEYOND_DECADES = 1.5  # the small-gain grid spans ω_e … ω_e · 10^1.5
BEYOND_N = 120


@dataclasses.dataclass(frozen=True)
class Evidence:
    """A measured FRF as evidence: ``omega (N,)`` rad/s, ``P (N, n, n)`` the measured plant
    ``Z_H Z_T⁻¹``; ``mismatch`` the bound ``m`` on ``σ̄(P P̂⁻¹)`` beyond ``omega[-1]``;
    ``kappa`` the small-gain level; ``source`` a label for reports; ``ts`` (s) the sampling
    period the controller runs at (``None``: continuous controller) — with it the measured
    loop uses the discretized controller (its phase lag is part of the loop) and the
    small-gain grid ends at the Nyquist frequency."""

    omega: np.ndarray
    P: np.ndarray
    mismatch: float
    kappa: float = KAPPA
    source: str = "frf"
    ts: float | None = None

    @property
    def omega_e(self) -> float:
        """Highest measured frequency (rad/s): the top of the evidence band."""
        return float(self.omega[-1])

    @property
    def g_max(self) -> float:
        """Largest ``|g(jω)|`` allowed on ``ω ≥ ω_e``: ``κ / m``."""
        return float(self.kappa / self.mismatch)


def mismatch_sigma(P, model, omega) -> np.ndarray:
    """``σ̄(P P̂⁻¹)`` per frequency ``(N,)``: how far the measured plant is from the model
    the controller inverts."""
    Ph = model.P(1j * jnp.asarray(omega, dtype=float))
    M = np.asarray(plant(jnp.asarray(P), Ph))  # the right division P P̂⁻¹
    return np.linalg.svd(M, compute_uv=False)[:, 0]


def mismatch_bound(P, model, omega, top: float = TOP_BAND) -> float:
    """Default bound ``m`` on ``σ̄(P P̂⁻¹)`` beyond the evidence: its largest measured value
    on ``[top · ω_e, ω_e]`` (at least 1). An assumption (the data end at ``ω_e``): the
    mismatch does not grow past what the top of the band shows."""
    omega = np.asarray(omega, dtype=float)
    s = mismatch_sigma(P, model, omega)
    sel = omega >= top * omega[-1]
    return float(max(1.0, np.max(s[sel])))


def evidence_from_frf(frf, model, *, f_max_hz: float | None = None, mismatch: float | None = None,
                      kappa: float = KAPPA, source: str = "frf", ts: float | None = None) -> Evidence:  # fmt: skip
    """:class:`Evidence` of an FRF (anything with ``omega``, ``Z_H``, ``Z_T``; a dict such as
    :attr:`PosteriorSamples.predictive` too), optionally cut at ``f_max_hz``."""
    d = measured_data(frf)
    om = np.asarray(d["omega"], dtype=float)
    P = measured_plant(d["Z_H"], d["Z_T"])
    if f_max_hz is not None:
        keep = om <= 2 * np.pi * f_max_hz * (1 + 1e-9)
        om, P = om[keep], P[keep]
    if om.size < 2 or not np.all(np.isfinite(P)):
        raise ValueError("evidence: the FRF needs ≥ 2 frequencies with finite, invertible Z_T")
    m = mismatch_bound(P, model, om) if mismatch is None else float(mismatch)
    if not (m > 0 and 0 < kappa < 1):
        raise ValueError(f"evidence: need mismatch > 0 and 0 < kappa < 1, got {m}, {kappa}")
    if ts is not None and not om[-1] < np.pi / ts:
        raise ValueError("evidence: the FRF reaches the Nyquist frequency of the controller's ts")
    return Evidence(om, P, m, float(kappa), source, None if ts is None else float(ts))


def beyond_grid(ev: Evidence, n: int = BEYOND_N) -> np.ndarray:
    """Log grid (rad/s) on ``[ω_e, ω_e · 10^BEYOND_DECADES]`` (with ``ev.ts``: up to the
    Nyquist frequency) where the small-gain condition is imposed."""
    top = ev.omega_e * 10.0**BEYOND_DECADES
    if ev.ts is not None:
        top = np.pi / ev.ts * (1.0 - 1e-9)
    return np.geomspace(ev.omega_e, top, n)


def small_gain_constraint(g: Compensator, omega, g_max: float, beta: float = 60.0, ts=None):
    """Smooth ``log max_ω |g(jω)| − log g_max`` (soft maximum, sharpness ``beta``; ``g`` of the
    sampled controller with ``ts``): ≤ 0 when the beyond-evidence small-gain condition holds
    (the soft maximum is ≥ the maximum)."""
    lg = jnp.log(jnp.abs(g_response(g, jnp.asarray(omega), ts)))
    return jax.nn.logsumexp(beta * lg) / beta - np.log(g_max)


def beyond_gain(g: Compensator, ev: Evidence) -> float:
    """``max_{ω ≥ ω_e} |g(jω)| · m`` (on :func:`beyond_grid`): the bound on σ̄(L) beyond the
    evidence; ≤ ``ev.kappa`` certifies it."""
    return float(
        np.max(np.abs(np.asarray(g_response(g, beyond_grid(ev, 400), ev.ts)))) * ev.mismatch
    )


def measured_loop(ev: Evidence, model, g: Compensator) -> np.ndarray:
    """``L = P_meas G`` ``(N, n, n)`` at the evidence frequencies: the measured plant in loop
    with the inverse-model controller of ``(model, g)`` (discretized with ``ev.ts``)."""
    return ev.P @ np.asarray(make_controller(model, g, ts=ev.ts).response(ev.omega))


def _return_difference(L) -> float:
    return float(np.min(np.linalg.svd(np.eye(L.shape[-1]) + L, compute_uv=False)[:, -1]))


def _loci_distance(L) -> float:
    return float(np.min(np.abs(1.0 + np.linalg.eigvals(L))))


def frf_return_difference(ev: Evidence, model, g: Compensator) -> float:
    """``min_ω σ̲(I + P_meas G)`` over the evidence: the measured loop's distance to −1 (a
    return difference, not a Nyquist count: the FRF is too sparse to count encirclements);
    ≥ 1/2 means disk margins of 6 dB / 29° at the measured frequencies."""
    return _return_difference(measured_loop(ev, model, g))


def frf_loci_distance(ev: Evidence, model, g: Compensator) -> float:
    """``min_ω min_i |1 + λ_i(P_meas G)|`` over the evidence: the measured loop's
    characteristic loci's distance to −1 — the rule the tuner's disc constraint and the
    analysis' loci margins use (≥ 1/2 at every measured frequency: a locus crossing the
    negative real axis there has GM ≥ 6 dB, one crossing the unit circle PM ≥ 29°). Never
    smaller than :func:`frf_return_difference` (``σ̲(I + L) ≤ min_i |1 + λ_i|``)."""
    return _loci_distance(measured_loop(ev, model, g))


def nominal_stable(model, g: Compensator) -> bool:
    """Is the loop stable on the model's own plant ``P̂`` (``L = g I``)? Nyquist on the wide
    continuous grid with the controller's RHP poles (roots of det Ẑ_H with Re > 0): a model
    whose Ẑ_H has RHP roots cancels them unstably, and no g fixes that — the Nyquist count
    inside the evidence band is the model's, so the certificate needs it."""
    om = continuous_grid(800)
    rep = pipeline.loop(pipeline.controller(model, g), pipeline.model_plant(model, om),
                        pipeline.SPEC_VERDICT)  # fmt: skip
    return bool(rep.stable)


@dataclasses.dataclass(frozen=True)
class Certificate:
    """What a measured FRF certifies about one loop (:func:`certificate`).

    - ``frf_min_loci_distance``: ``min |1 + λ_i(L_meas)|`` over the measured frequencies
      (:func:`frf_loci_distance`), the figure the certificate judges.
    - ``frf_min_sigma_I_plus_L``: ``min σ̲(I + L_meas)`` (:func:`frf_return_difference`, the
      stricter disk view), reported only.
    - ``beyond_loop_gain``: ``max |g| · m`` above the evidence (:func:`beyond_gain`).
    - ``evidence_hz``: the top of the evidence ``ω_e / 2π`` (Hz); ``mismatch_bound``: ``m``.
    - ``nominal_stable``: the loop on the model's own plant is stable (:func:`nominal_stable`).
    - ``certified``: nominal loop stable, loci distance ≥ ``floor`` at every measured frequency
      and beyond-band gain ≤ κ.
    """

    frf_min_loci_distance: float
    frf_min_sigma_I_plus_L: float
    beyond_loop_gain: float
    evidence_hz: float
    mismatch_bound: float
    nominal_stable: bool
    certified: bool

    @property
    def status(self) -> Verdict:
        """``PASSED`` when :attr:`certified`, else ``FAILED``."""
        return Verdict.PASSED if self.certified else Verdict.FAILED

    @property
    def ok(self) -> bool:
        """Same as :attr:`certified`."""
        return self.certified

    def figures(self) -> dict:
        """The fields as Python floats and bools (the design file's certificate columns)."""
        return dataclasses.asdict(self)

    def summary(self) -> dict:
        """Strict-JSON summary: ``status``, ``ok`` and :meth:`figures` (NaN → ``None``)."""
        return jsonable({"status": self.status, "ok": self.ok, **self.figures()})


def certificate(ev: Evidence, model, g: Compensator, floor: float = 0.5) -> Certificate:
    """The :class:`Certificate` of ``g`` on the evidence ``ev``. The measured FRF is too
    sparse to count encirclements: the count comes from the model (and the held-out draws),
    the FRF keeps the measured loci away from −1 (the rule the tuner's disc constraint and the
    GM/PM of the analysis use), and the small gain fixes the count beyond the data."""
    L = measured_loop(ev, model, g)  # once for both in-band figures
    ld, rd, bg = _loci_distance(L), _return_difference(L), beyond_gain(g, ev)
    ns = bool(nominal_stable(model, g))
    return Certificate(float(ld), float(rd), float(bg), float(ev.omega_e / (2 * np.pi)),
                       float(ev.mismatch), ns, bool(ns and ld >= floor and bg <= ev.kappa + 1e-9))  # fmt: skip
