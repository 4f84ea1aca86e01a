# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""What :func:`~hapid.control.loop_metrics` is asked for and what it returns: :class:`MetricsSpec`
(static, hashable), :class:`LoopMetrics` (0-d arrays, or ``(B,)`` when vmapped), the scalar
fields ``_SCALARS`` a result reports, and the iso-bandwidth threshold ``1 − 1/√2``."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import numpy as np
from jaxtyping import Array, Bool, Complex, Float

from .. import _config  # noqa: F401  (float64)
from .._plain import enum_members, jsonable
from ._loop import report_numbers
from ._status import LoopStatus

TWO_PI = 2.0 * np.pi
ISO_THRESHOLD = 1.0 - 1.0 / np.sqrt(2.0)


@dataclasses.dataclass(frozen=True)
class MetricsSpec:
    """What :func:`loop_metrics` computes (static, hashable). The verdict is always computed.

    - ``bandwidth``: iso-bandwidth (first ω where σ̄(T − I) reaches 1 − 1/√2), refined.
    - ``margins``: worst gain/phase margins over the characteristic loci, refined.
    - ``t_peak``: peak of σ̄(T) and its frequency, refined.
    - ``disk``: balanced disk margin ``2/max σ̄(S − T)`` (peak refined).
    - ``arrays``: also the per-frequency ``freq_hz``, ``sv_T_minus_I`` (σ̄ only, ``(N,)``)
      and tracked ``loci`` ``(N, n)`` (costs the full eigenvalue stack).
    - ``singular_rtol``: ``I + L`` is flagged singular where σ̲(I+L) ≤ rtol·max(1, σ̄(I+L));
      ``max_phase_step``: largest allowed step (rad) of the unwrapped phase of det(I + L)
      and of every locus 1 + λᵢ (:func:`~hapid.control.nyquist_encirclements`).
    - ``n_candidates``: how many undecided grid points get exact values per step of the
      refinement loops (a work-size knob; results do not depend on it).
    - ``kernels``: ``"xla"`` (default) or ``"lapack"`` (LU/SVD custom calls; the reference
      the kernels are tested against).
    """

    bandwidth: bool = True
    margins: bool = True
    t_peak: bool = True
    disk: bool = False
    arrays: bool = False
    singular_rtol: float = 1e-9
    max_phase_step: float = float(np.pi / 2)
    n_candidates: int = 128
    kernels: str = "xla"
    # additions for the one-answer callers (analyze, paper, tune):
    # ``literal``: also the paper-literal iso-bandwidth (last upward crossing of σ̄(T − I)
    # over 1 − 1/√2, refined; exact σ̄ on the whole grid); ``full_sv``: ``sv_T_minus_I``
    # (with ``arrays``) holds every singular value ``(N, n)``, largest first (figures 5, 10).
    # ``disk`` also fills ``disk_gm_db``/``disk_pm_deg`` (from α, as ``disk_margin_from_peak``).
    literal: bool = False
    full_sv: bool = False


_SCALARS = (
    "stable",
    "n_encirclements",
    "n_closed_loop_rhp",
    "singular",
    "nyquist_resolved",
    "iso_bandwidth_hz",
    "gm_db",
    "gm_freq_hz",
    "pm_deg",
    "pm_freq_hz",
    "t_peak_db",
    "t_peak_hz",
    "disk_margin",
    "iso_bandwidth_literal_hz",
    "disk_gm_db",
    "disk_pm_deg",
)


class LoopMetrics(eqx.Module):
    """Result of :func:`loop_metrics` (0-d arrays, or ``(B,)`` when vmapped; Hz, dB, deg).

    Verdict: ``stable``, ``n_encirclements``, ``n_closed_loop_rhp``, ``singular``,
    ``nyquist_resolved`` (the rule of :func:`~hapid.control.nyquist_verdict`). Performance
    (NaN when not stable or not asked): ``iso_bandwidth_hz`` (0: above the threshold at the first grid
    point, inf: never reached), ``t_peak_db``/``t_peak_hz``. Margins (any loop, NaN when not
    asked; inf/NaN-frequency when no crossing): ``gm_db``/``gm_freq_hz``, ``pm_deg``/
    ``pm_freq_hz``. ``disk_margin`` (0 when not stable, NaN when not asked).
    ``exact_fallback``: always false (there is no whole-grid fallback any more; kept for callers).
    Arrays (``spec.arrays``, else ``None``): ``freq_hz (N,)``, ``sv_T_minus_I (N,)`` (σ̄),
    ``loci (N, n)``.
    """

    stable: Bool[Array, ...]
    n_encirclements: Float[Array, ...]
    n_closed_loop_rhp: Float[Array, ...]
    singular: Bool[Array, ...]
    nyquist_resolved: Bool[Array, ...]
    iso_bandwidth_hz: Float[Array, ...]
    gm_db: Float[Array, ...]
    gm_freq_hz: Float[Array, ...]
    pm_deg: Float[Array, ...]
    pm_freq_hz: Float[Array, ...]
    t_peak_db: Float[Array, ...]
    t_peak_hz: Float[Array, ...]
    disk_margin: Float[Array, ...]
    iso_bandwidth_literal_hz: Float[Array, ...]
    disk_gm_db: Float[Array, ...]
    disk_pm_deg: Float[Array, ...]
    exact_fallback: Bool[Array, ...]
    freq_hz: Float[Array, "... N"] | None = None
    sv_T_minus_I: Float[Array, "... N"] | None = None
    loci: Complex[Array, "... N n"] | None = None

    @property
    def ok(self):
        """True when the loop is stable with a resolved Nyquist count (bool array if batched)."""
        return self.stable & self.nyquist_resolved & ~self.singular

    @property
    def status(self):
        """:class:`LoopStatus` ``STABLE``, ``UNSTABLE``, ``SINGULAR`` (closed-loop pole on the
        axis) or ``UNRESOLVED`` (grid too coarse / not reaching the ends); an object array of
        them when batched."""
        st = np.asarray(self.stable)
        sg = np.asarray(self.singular)
        rs = np.asarray(self.nyquist_resolved)
        out = np.where(
            sg, "singular", np.where(~rs, "unresolved", np.where(st, "stable", "unstable"))
        )
        return enum_members(out, LoopStatus)

    def numbers(self) -> dict:
        """Scalar fields as python ``bool``/``int``/``float`` (lists when batched), then
        ``status`` (its value) and ``ok``. Non-finite values stay ``nan``/``inf`` (for
        arithmetic; :meth:`summary` is the JSON form)."""
        return report_numbers(self, _SCALARS)

    def summary(self) -> dict:
        """Strict-JSON dict: :meth:`numbers` with non-finite values as ``None``."""
        return jsonable(self.numbers())
