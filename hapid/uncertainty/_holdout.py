"""Leave-one-frequency-out check of the ``params`` predictive band of ``P``:
:func:`holdout_check` → :class:`HoldoutCheck`.

The band of :func:`~hapid.uncertainty.predictive_plants` between two measured frequencies is
an interpolation of the model error (a GP conditioned on the fit residuals). Where the
misfit changes faster than the GP allows, the band is too narrow there (docs/conventions.md,
"Where in frequency") and nothing in the band itself shows it. This check asks the data:
each interior measured frequency ``ω_k`` in turn is given no weight (its FRF variance
inflated far above everything else, so the GP conditions on the other frequencies only),
``P`` is drawn at ``ω_k`` with the measurement noise of ``ω_k`` added, and the measured
``P̂(ω_k) = Ẑ_H Ẑ_T⁻¹`` is compared with the band's ``level`` ball (the same ball as
:func:`~hapid.uncertainty.band_calibration`): radius ``r`` around the draws' median, error
``e`` of the measured ``P``. Where ``e > r`` the left-out measurement is outside the band's
own ``level`` ball, evidence that the band does not hold between its neighbours: the
interval ``(ω_{k−1}, ω_{k+1})`` is *not established*. The rule has no tuned constant: the
ball is the band's own.

What it cannot see: a misfit that peaks between two measured frequencies and is small at
both (the band can miss there while every left-out point holds), and the frequencies outside
the measured ones (:meth:`HoldoutCheck.covers`). It is a cheap leave-one-out: the
parameter draws and the hyperparameters are those of the full posterior (conditioned on
``ω_k`` too), so it checks the interpolation, not the fit. Under an exactly calibrated band
each left-out point falls outside with probability ``1 − level``, so a long list of checked
frequencies can flag one by chance. The check is of the model-error kinds that condition
on residuals (``gp``, ``gp_corr``). What it found on devices that chose nothing:
docs/conventions.md, "Where in frequency".
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from .._plain import jsonable
from ..impedance import plant
from ..samples import PosteriorSamples
from ._model_error import GP, model_error_for
from ._predictive import credible_ball, predictive_plants

INFLATE = 1e10
"""The left-out frequency's FRF variance is raised by ``INFLATE × (a_H + a_M)²`` (the data's
RMS element sizes there): ~10¹⁰ times the model error's own variance, so its weight in the
GP conditional is ~10⁻¹⁰."""


class HoldoutStatus(enum.StrEnum):
    """Verdict of a :class:`HoldoutCheck`."""

    ESTABLISHED = "established"
    NOT_ESTABLISHED = "not established"


@dataclasses.dataclass(frozen=True)
class HoldoutCheck:
    """The leave-one-frequency-out check (module docstring).

    - ``freq_hz (K,)``: the measured frequencies left out in turn (Hz);
    - ``radius (K,)``: the ``level`` ball's radius of the draws at each (Frobenius norm of
      ``P``, dimensionless, measurement noise included);
    - ``error (K,)``: ``‖P̂ − P̃‖_F``, the measured ``P`` against the draws' median;
    - ``measured_hz (Nf,)``: every measured frequency of the fit (Hz);
    - ``level``: the credible level of the ball;
    - ``lead (K, 2)``, ``rest (K, 2)``: the left-out error and the draws' spread split by
      direction (:func:`~hapid.uncertainty.direction_split`): ``[:, 0]`` the squared error,
      ``[:, 1]`` the draws' mean square about their median, measurement noise included (both
      dimensionless), along the leading singular pair of
      the draws' median (``lead``) and over the other ``n² − 1`` entries of that basis
      (``rest``). :func:`~hapid.uncertainty.recalibration` reads them.
    """

    freq_hz: np.ndarray
    radius: np.ndarray
    error: np.ndarray
    measured_hz: np.ndarray
    level: float
    lead: np.ndarray
    rest: np.ndarray

    @property
    def held(self) -> np.ndarray:
        """``(K,)`` bool: the measured ``P`` inside the ball (``error ≤ radius``)."""
        return self.error <= self.radius

    @property
    def ratio(self) -> np.ndarray:
        """``(K,)`` radius ÷ error (below 1: outside)."""
        return self.radius / np.maximum(self.error, 1e-300)

    @property
    def missed_hz(self) -> np.ndarray:
        """The left-out frequencies whose measured ``P`` did not hold (Hz)."""
        return self.freq_hz[~self.held]

    @property
    def not_established_hz(self) -> list[tuple[float, float]]:
        """The intervals ``(f_{k−1}, f_{k+1})`` (Hz) around each missed frequency ``f_k``,
        overlapping ones merged, ascending."""
        f = self.measured_hz
        out: list[list[float]] = []
        for fk in self.missed_hz:
            k = int(np.argmin(np.abs(f - fk)))
            lo, hi = float(f[k - 1]), float(f[k + 1])
            if out and lo <= out[-1][1]:
                out[-1][1] = max(out[-1][1], hi)
            else:
                out.append([lo, hi])
        return [(a, b) for a, b in out]

    @property
    def status(self) -> HoldoutStatus:
        if self.held.all():
            return HoldoutStatus.ESTABLISHED
        return HoldoutStatus.NOT_ESTABLISHED

    @property
    def ok(self) -> bool:
        """Every left-out measured ``P`` inside its ball."""
        return self.status is HoldoutStatus.ESTABLISHED

    def within(self, freq_hz) -> np.ndarray:
        """``(N,)`` bool: the frequencies ``freq_hz`` (Hz) within the measured ones
        (``measured_hz[0] ≤ f ≤ measured_hz[-1]``), the range the left-out frequencies test;
        outside it the band is an extrapolation."""
        f = np.asarray(freq_hz, dtype=float)
        return (f >= self.measured_hz[0]) & (f <= self.measured_hz[-1])

    def covers(self, freq_hz) -> np.ndarray:
        """``(N,)`` bool: the frequencies ``freq_hz`` (Hz) where the check establishes the
        band: within the measured frequencies (``measured_hz[0] ≤ f ≤ measured_hz[-1]``;
        outside them the band is an extrapolation no left-out frequency tests) and outside
        every not-established interval (open intervals: the measured end points themselves
        are data)."""
        f = np.asarray(freq_hz, dtype=float)
        ok = self.within(f)
        for lo, hi in self.not_established_hz:
            ok &= ~((f > lo) & (f < hi))
        return ok

    def message(self) -> str:
        """One line for the CLI: the verdict first, then the evidence and the remedy."""
        k, m = self.freq_hz.size, int((~self.held).sum())
        pct = f"{100 * self.level:.0f} %"
        span = f"{self.freq_hz[0]:.4g}–{self.freq_hz[-1]:.4g} Hz" if k else "none"
        if self.ok:
            return (f"check: band established between the measured frequencies: each of the "
                    f"{k} interior ones ({span}), left out in turn, fell inside its {pct} band "
                    "predicted from the rest (a misfit that peaks between two measured "
                    "frequencies and is small at both is not seen: docs/conventions.md)")  # fmt: skip
        gaps, miss, mids = self._listed()
        more = (f"measure more frequencies there (e.g. {mids} Hz)" if mids else
                "measure there on a finer frequency grid (a longer period: the measured "
                "frequencies are adjacent on theirs)")  # fmt: skip
        return (f"check: band NOT ESTABLISHED at {gaps}: left out in turn, the measured P at "
                f"{miss} Hz fell outside its {pct} band predicted from the other frequencies "
                f"({k - m} of {k} interior ones inside): there the band is an interpolation the "
                f"data contradict, not a bound. To establish it, {more} and rerun hapid "
                "posterior")  # fmt: skip

    def evidence_message(self) -> str:
        """One line for the CLI when the band is recalibrated on this check
        (:func:`~hapid.uncertainty.recalibration`): the verdict is of the band as drawn, which
        the draws file no longer holds, so the line reads as evidence, not as a verdict."""
        pct = f"{100 * self.level:.0f} %"
        if self.ok:
            return (f"check of the band as drawn: each of the {self.freq_hz.size} interior "
                    f"measured frequencies, left out in turn, fell inside its {pct} band "
                    "predicted from the rest")  # fmt: skip
        gaps, miss, mids = self._listed()
        more = f" (e.g. {mids} Hz)" if mids else " (a finer frequency grid: a longer period)"
        return (f"check of the band as drawn: left out in turn, the measured P at {miss} Hz fell "
                f"outside its {pct} band predicted from the other frequencies (not established "
                f"as drawn: {gaps}); the recalibration below carries those errors into the "
                f"band. Measuring more frequencies there{more} would narrow it")  # fmt: skip

    def _listed(self) -> tuple[str, str, str]:
        """The not-established intervals, the missed and the suggested frequencies as
        comma-separated text (Hz)."""
        gaps = ", ".join(f"{lo:.4g}–{hi:.4g} Hz" for lo, hi in self.not_established_hz)
        miss = ", ".join(f"{f:.4g}" for f in self.missed_hz)
        mids = ", ".join(f"{f:.4g}" for f in self.suggested_hz)
        return gaps, miss, mids

    @property
    def suggested_hz(self) -> list[float]:
        """Frequencies to measure (Hz): the geometric midpoint of each pair of consecutive
        measured frequencies in a not-established interval, rounded to the measured
        frequencies' own grid (their greatest common step, to 1 mHz). A pair with no grid
        point between them gives none (there a finer grid, a longer period, is needed)."""
        step = _grid_step(self.measured_hz)
        out = []
        for lo, hi in self.not_established_hz:
            for a, b in _pairs(self.measured_hz, lo, hi):
                m = float(np.sqrt(a * b))
                if step > 0:
                    m = round(m / step) * step
                if a < m < b:
                    out.append(m)
        return out

    def summary(self) -> dict:
        """Strict-JSON summary: status, ok, level, the left-out frequencies with their ratio
        and verdict, and the not-established intervals (Hz)."""
        return jsonable({"status": self.status, "ok": self.ok, "level": self.level,
                         "freq_hz": self.freq_hz, "ratio": self.ratio, "held": self.held,
                         "not_established_hz": [list(p) for p in self.not_established_hz],
                         "suggested_hz": self.suggested_hz})  # fmt: skip


def _grid_step(f) -> float:
    """The greatest common step (Hz, to 1 mHz) of the frequencies ``f``; 0 when there is
    none coarser than 1 mHz."""
    milli = np.round(np.asarray(f, dtype=float) * 1000.0).astype(np.int64)
    if np.any(np.abs(milli / 1000.0 - np.asarray(f)) > 1e-6):
        return 0.0
    return float(np.gcd.reduce(milli)) / 1000.0


def _pairs(f, lo, hi):
    """Consecutive measured frequencies ``(a, b)`` within ``[lo, hi]``."""
    inside = f[(f >= lo) & (f <= hi)]
    return zip(inside[:-1], inside[1:], strict=True)


def holdout_check(ps: PosteriorSamples, *, max_samples: int = 200, seed: int = 0,
                  level: float = 0.9) -> HoldoutCheck:  # fmt: skip
    """Leave each interior measured frequency out in turn and check the ``params`` band of
    ``P`` there against the measured ``P`` (module docstring). ``ps``: posterior samples of a
    GP model error (``gp`` or ``gp_corr``) that carry their fit data; at most
    ``max_samples`` draws per frequency (``seed``).

    Raises ``ValueError`` for samples without fit data, a model error that does not
    condition on the residuals (``none``, ``white``), fewer than three measured frequencies or
    a ``level`` outside (0, 1).
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"holdout_check: level must be in (0, 1), got {level}")
    d = ps.predictive
    if d is None:
        raise ValueError("holdout_check: these samples carry no fit data (rerun hapid posterior)")
    if not isinstance(model_error_for(ps), GP):
        raise ValueError(f"holdout_check: the {ps.error_kind!r} model error does not condition "
                         "on the fit residuals; the check needs gp or gp_corr samples")  # fmt: skip
    om = np.asarray(d["omega"], dtype=float)
    if om.size < 3:
        raise ValueError(f"holdout_check: needs at least 3 measured frequencies, got {om.size}")
    P_meas = np.asarray(plant(np.asarray(d["Z_H"]), np.asarray(d["Z_T"])))  # (Nf, n, n)
    vH, vT = np.asarray(d["var_H"]), np.asarray(d["var_T"])
    big = INFLATE * (np.asarray(d["a_H"]) + np.asarray(d["a_M"])) ** 2
    rho = float(d["noise_corr"])
    rng = np.random.default_rng(seed)
    radius, error, split = [], [], []
    for k in range(1, om.size - 1):
        vH2, vT2 = vH.copy(), vT.copy()
        vH2[k] += big[k]
        vT2[k] += big[k]
        ps_k = dataclasses.replace(ps, predictive={**d, "var_H": vH2, "var_T": vT2})
        pp = predictive_plants(ps_k, om[k : k + 1], max_samples=max_samples, seed=seed + k)
        z1, z2 = _circular(rng, pp.Z_H.shape), _circular(rng, pp.Z_H.shape)
        zh = pp.Z_H + np.sqrt(vH[k]) * z1  # the measurement of ω_k: its own noise
        zt = pp.Z_T + np.sqrt(vT[k]) * (rho * z1 + np.sqrt(1.0 - rho**2) * z2)
        draws = np.asarray(plant(zh, zt))  # (S, 1, n, n)
        med, _, r = credible_ball(draws, level)  # (1, n, n), (1,)
        radius.append(float(r[0]))
        error.append(float(np.linalg.norm(P_meas[k] - med[0])))
        split.append(direction_split(draws, P_meas[k : k + 1], med)[:, 0])  # (2, 2)
    f = om / TWO_PI
    sp = np.asarray(split)  # (K, 2 parts, 2)
    return HoldoutCheck(f[1:-1], np.asarray(radius), np.asarray(error), f, float(level),
                        lead=sp[:, 0], rest=sp[:, 1])  # fmt: skip


def direction_split(draws, truth, median=None) -> np.ndarray:
    """``(2, N, 2)``: the error of ``truth (N, n, n)`` from the draws' median and the spread of
    the ``draws (S, N, n, n)`` (complex), split by direction in the singular basis of the
    median ``M = U Σ Vᴴ`` (elementwise re/im median unless ``median (N, n, n)`` is given):
    with ``E = Uᴴ (truth − M) V`` and ``X_s = Uᴴ (draws_s − M) V``, row 0 is the leading
    entry (``[|E₁₁|², mean_s |X_s,₁₁|²]``), row 1 the other ``n² − 1`` entries (``[‖E‖² −
    |E₁₁|², mean_s (‖X_s‖² − |X_s,₁₁|²)]``). The plant's misfit concentrates in the leading
    direction (docs/conventions.md, "Where the 6-rod miss lies"); an error model the same
    size in every entry spreads its variance over all ``n²``."""
    M, U, Vh, D = median_frame(draws, median)  # D: (S, N, n, n)
    E = _rotated(np.asarray(truth)[None], M, U, Vh)[0]  # (N, n, n)
    e1, et = np.abs(E[..., 0, 0]) ** 2, np.sum(np.abs(E) ** 2, axis=(-2, -1))
    v1 = np.mean(np.abs(D[..., 0, 0]) ** 2, axis=0)
    vt = np.mean(np.sum(np.abs(D) ** 2, axis=(-2, -1)), axis=0)
    return np.stack([np.stack([e1, v1], -1), np.stack([et - e1, vt - v1], -1)])


def median_frame(draws, median=None):
    """``(M, U, Vh, D)``: the draws' elementwise re/im median ``M (N, n, n)`` (or ``median``),
    its singular basis ``M = U Σ Vh`` and each draw's deviation in that basis,
    ``D = Uᴴ (draws − M) V`` ``(S, N, n, n)``, for draws ``(S, N, n, n)`` (complex);
    ``M + U D Vh`` gives the draws back."""
    X = np.asarray(draws)
    M = credible_ball(X, 0.5)[0] if median is None else np.asarray(median)
    U, _, Vh = np.linalg.svd(M)
    return M, U, Vh, _rotated(X, M, U, Vh)


def _rotated(X, M, U, Vh):
    """``Uᴴ (X − M) V`` for ``X (S, N, n, n)``."""
    return U.conj().swapaxes(-1, -2)[None] @ (X - M[None]) @ Vh.conj().swapaxes(-1, -2)[None]


def _circular(rng, shape):
    """Circular complex standard normals (unit variance) of ``shape``."""
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) * np.sqrt(0.5)
