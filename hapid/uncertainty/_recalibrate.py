"""The ``params`` band of ``P`` recalibrated on its own left-out errors:
:func:`recalibration` → :class:`Recalibration`, whose :meth:`~Recalibration.apply` returns
the recalibrated draws.

Why: the band of :func:`~hapid.uncertainty.predictive_plants` puts the same model-error
variance in every element of ``Z_H`` and ``Z_M``, while the plant's misfit concentrates along
the leading singular pair of ``P``, and the band is too wide where the misfit is small
(docs/conventions.md, "Where the 6-rod miss lies"). The leave-one-frequency-out check
(:func:`~hapid.uncertainty.holdout_check`) measures both at every interior measured
frequency ``f_k``, split by direction (:attr:`HoldoutCheck.lead`, :attr:`HoldoutCheck.rest`):
the squared error ``e`` of the left-out measurement and the draws' variance ``v`` there.

How, per frequency ``f`` of the band and per direction (the leading singular pair of the
draws' median, and the other ``n² − 1`` entries of that basis), about the draws' median:

- **shrink** the draws' spread by ``λ = √clip(z̄(f), SHRINK_FLOOR, 1)``, ``z̄`` the
  left-out ``e / v`` averaged with Gaussian weights in ``ln f`` (width :data:`KERNEL_LN_F`)
  together with :data:`PSEUDO` observations of 1 (so a few small ratios shrink little). Only
  shrinks: where the band holds its left-out errors with room to spare it is narrowed;
- **add** an independent circular term of variance ``c² max(e − v, 0) · 4t(1 − t)``
  (``c =`` :data:`EXCESS_FRACTION`; ``e − v`` the larger of the two left-out frequencies
  around ``f``, the end one beyond them): the part of the left-out error the band did not
  carry, shaped over each gap between measured frequencies (``t ∈ [0, 1]`` the position of
  ``f`` in its gap, in ``ln f``; the shape is 1 outside the measured frequencies): an
  interpolation error is 0 at the measured ends (there the band carries the measurement's
  own error) and largest midway. Spread over the ``n² − 1`` entries evenly for ``rest``.
  Added, not a multiplicative widening: between measured frequencies the GP's variance falls
  faster than the error does, so the added size is the error's own. ``c = 1/2`` because a
  left-out frequency sits twice as far from its neighbours as a band frequency from its
  nearest measurement.

How the constants were chosen and on which devices the result was judged:
docs/conventions.md, "Recalibrated band"; the figures: benchmarks/README.md.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._holdout import HoldoutCheck, _circular, median_frame

EXCESS_FRACTION = 0.5
"""``c``: the added term's standard deviation as a fraction of the left-out excess error."""

SHRINK_FLOOR = 0.25
"""The smallest variance factor of the shrink (the spread never falls below half)."""

KERNEL_LN_F = 0.3
"""Width (natural-log units of frequency) of the Gaussian weights of the shrink's average."""

PSEUDO = 2.0
"""Observations of ratio 1 added to the shrink's average (its prior weight)."""


@dataclasses.dataclass(frozen=True)
class Recalibration:
    """Per frequency ``freq_hz (N,)`` (Hz) and per direction — column 0 the leading singular
    pair of the draws' median, column 1 the other ``n² − 1`` entries — the shrink factor of
    the spread ``shrink (N, 2)`` (in (0, 1]) and the added variance ``add (N, 2)``
    (dimensionless, as ``|P|²``; column 1 in total over its entries). Module docstring."""

    freq_hz: np.ndarray
    shrink: np.ndarray
    add: np.ndarray

    def apply(self, P, seed: int = 0) -> np.ndarray:
        """The recalibrated draws ``(S, N, n, n)`` of draws ``P (S, N, n, n)`` (complex) on
        :attr:`freq_hz`: about the elementwise re/im median ``M = U Σ Vᴴ``, each draw's
        deviation in that basis scaled by :attr:`shrink` and a circular normal term of
        variance :attr:`add` added (``seed``). Raises ``ValueError`` for another grid."""
        X = np.asarray(P)
        if X.ndim != 4 or X.shape[1] != self.freq_hz.size or X.shape[-1] != X.shape[-2]:
            raise ValueError(f"Recalibration.apply: draws (S, {self.freq_hz.size}, n, n), got "
                             f"{X.shape}")  # fmt: skip
        if not np.all(np.isfinite(X)):
            raise ValueError("Recalibration.apply: the draws hold non-finite values")
        n = X.shape[-1]
        M, U, Vh, D = median_frame(X)
        scale = np.broadcast_to(self.shrink[:, 1, None, None], (X.shape[1], n, n)).copy()
        scale[:, 0, 0] = self.shrink[:, 0]
        sd = np.broadcast_to(np.sqrt(self.add[:, 1] / max(n * n - 1, 1))[:, None, None],
                             scale.shape).copy()  # fmt: skip
        sd[:, 0, 0] = np.sqrt(self.add[:, 0])
        rng = np.random.default_rng([seed, 1])  # a stream of its own, not the draws' seed
        D = D * scale[None] + _circular(rng, D.shape) * sd[None]
        return M[None] + U[None] @ D @ Vh[None]

    def summary(self) -> dict:
        """Strict-JSON summary: the frequency range and the range of each factor per
        direction."""
        return {"f_min_hz": float(self.freq_hz[0]), "f_max_hz": float(self.freq_hz[-1]),
                "shrink_lead": [float(self.shrink[:, 0].min()), float(self.shrink[:, 0].max())],
                "shrink_rest": [float(self.shrink[:, 1].min()), float(self.shrink[:, 1].max())],
                "add_lead_max": float(self.add[:, 0].max()),
                "add_rest_max": float(self.add[:, 1].max())}  # fmt: skip


def recalibration(check: HoldoutCheck, freq_hz) -> Recalibration:
    """The :class:`Recalibration` of a band on ``freq_hz (N,)`` (Hz, positive) from a
    :class:`~hapid.uncertainty.HoldoutCheck` of the same samples (module docstring). Raises
    ``ValueError`` for a check with no left-out frequency, a non-finite direction split or a
    bad grid."""
    f = np.asarray(freq_hz, dtype=float)
    if f.ndim != 1 or f.size < 1 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError("recalibration: freq_hz must be a 1-D array of positive frequencies (Hz)")
    fk = np.asarray(check.freq_hz, dtype=float)
    if fk.size < 1:
        raise ValueError("recalibration: the check left out no frequency (fewer than 3 measured)")
    parts = (np.asarray(check.lead, dtype=float), np.asarray(check.rest, dtype=float))
    if any(p.shape != (fk.size, 2) or not np.all(np.isfinite(p)) for p in parts):
        raise ValueError("recalibration: the check's direction split (lead, rest) must be finite "
                         f"({fk.size}, 2) arrays")  # fmt: skip
    tiny = 1e-300
    shrink, add = [], []
    w = np.exp(-0.5 * ((np.log(f)[:, None] - np.log(fk)[None]) / KERNEL_LN_F) ** 2)  # (N, K)
    j = np.searchsorted(fk, f)  # the left-out frequencies around f (the end one beyond them)
    lo, hi = np.clip(j - 1, 0, fk.size - 1), np.clip(j, 0, fk.size - 1)
    gap = gap_shape(f, check.measured_hz)
    for ev in parts:
        e, v = ev[:, 0], ev[:, 1]
        z = e / np.maximum(v, tiny)
        zbar = (w @ z + PSEUDO) / (w.sum(axis=1) + PSEUDO)
        shrink.append(np.sqrt(np.clip(zbar, SHRINK_FLOOR, 1.0)))
        excess = EXCESS_FRACTION**2 * np.maximum(e - v, 0.0)
        add.append(np.maximum(excess[lo], excess[hi]) * gap)
    return Recalibration(f, np.stack(shrink, -1), np.stack(add, -1))


def gap_shape(freq_hz, measured_hz) -> np.ndarray:
    """``(N,)``: ``4t(1 − t)`` with ``t`` the position of each ``freq_hz`` (Hz) in its gap
    between consecutive ``measured_hz`` (in ``ln f``): 0 at a measured frequency, 1 midway;
    1 outside the measured range."""
    f, m = np.asarray(freq_hz, dtype=float), np.asarray(measured_hz, dtype=float)
    if m.size < 2:
        return np.ones(f.shape)
    j = np.clip(np.searchsorted(m, f) - 1, 0, m.size - 2)
    t = np.log(f / m[j]) / np.log(m[j + 1] / m[j])
    inside = (f >= m[0]) & (f <= m[-1])
    return np.where(inside, np.clip(4.0 * t * (1.0 - t), 0.0, 1.0), 1.0)
