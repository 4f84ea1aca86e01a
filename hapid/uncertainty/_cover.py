"""What a robust check's draws are evidence of: the measured band and the loop beyond it.

Draws of the loop conditioned on a measured FRF (:mod:`hapid.uncertainty._loopgp`) say
something about the true loop only where the FRF was measured, ``[f₁, f_e]``. Above ``f_e``
every draw is the model's own plant, so a crossing of −1 that the true plant makes there is
in no draw; below ``f₁`` the draws continue as a stated assumption. The requirement check
(:attr:`hapid.uncertainty.RobustReport.check`) therefore says ``passed`` only when

1. the loop is small-gain above the measured band: ``max_{ω ≥ ω_e} |g(jω)| · m ≤ κ``
   (``m`` the mismatch bound of :func:`hapid.tune._evidence.mismatch_bound`, ``κ = 1/2``):
   then no plant within the bound can change the Nyquist count there and any crossing of
   the negative real axis there has ``GM ≥ 1/κ`` (:mod:`hapid.tune._evidence`), and
2. the crossings that decide the margins' 5 % quantiles — the gain and phase crossover
   frequencies of the draws in the worst decile of ``|GM|`` and of ``|PM|`` — do not lie
   below the measured band (above it, 1 covers them: no gain crossover, ``GM ≥ 1/κ``), and
3. the phase margin is not decided in a *measurement gap* by less than
   :data:`~hapid.defaults.GAP_PM_DEG` (:func:`gap_check`): when the 5 % quantile of ``|PM|``
   exceeds the requirement by less than that and the gain crossovers that decide it lie
   between two measured frequencies more than :data:`~hapid.defaults.GAP_RATIO` apart, the
   margin is the draws' interpolation, which was seen to miss the true locus's phase there
   by up to that much.

Otherwise the check is ``not established``, with the reason and what would establish it
(measure the FRF to a higher / lower frequency, or lower ``|g|`` above ``f_e``). A check that
fails on the draws stays ``failed``: the draws are the evidence at hand (unless it fails only
through draws whose Nyquist count the grid did not resolve:
:meth:`~hapid.uncertainty.RobustReport.failed_check`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..defaults import GAP_PM_DEG, GAP_RATIO
from ..verdict import Check, Verdict

DECIDING_QUANTILE = 0.10  # the draws whose margins decide the 5 % quantile: the worst decile
BAND_SLACK = 1e-6  # relative tolerance on the band's ends (refined crossings at the end points)


@dataclasses.dataclass(frozen=True)
class EvidenceCover:
    """What the draws of a robust check are conditioned on.

    Attributes:
        measured_hz: ``(f₁, f_e)`` Hz, the measured band the draws are conditioned on.
        beyond_loop_gain: bound on ``σ̄(L)`` above ``f_e`` (``max |g| · m``).
        kappa: the small-gain level that covers the loop above ``f_e`` (1/2).
        clear_hz: the frequency (Hz) above which ``|g| · m ≤ κ`` holds on the checked grid
            (the FRF would have to reach it); NaN when it never holds there.
        g_max: the largest ``|g|`` above ``f_e`` that ``κ`` allows (``κ / m``).
        loop: the loop checked, e.g. ``"continuous-time controller"`` or
            ``"controller sampled at 1000 Hz"``.
        frequencies_hz: every measured frequency (Hz, increasing), for the gap rule
            (:func:`gap_check`); empty: not known, the rule is not applied.
    """

    measured_hz: tuple
    beyond_loop_gain: float
    kappa: float
    clear_hz: float
    g_max: float
    loop: str
    frequencies_hz: tuple = ()

    @property
    def beyond_covered(self) -> bool:
        """The small-gain condition above the measured band holds."""
        return bool(self.beyond_loop_gain <= self.kappa + 1e-9)

    def summary(self) -> dict:
        """Strict-JSON dict of the attributes plus ``beyond_covered``."""
        out = dataclasses.asdict(self)
        out["measured_hz"] = [float(x) for x in self.measured_hz]
        out["frequencies_hz"] = [float(x) for x in self.frequencies_hz]
        out["clear_hz"] = None if not np.isfinite(self.clear_hz) else float(self.clear_hz)
        return out | {"beyond_covered": self.beyond_covered}


def deciding_frequencies(report) -> dict:
    """``{"gm": (K,) Hz, "pm": (K,) Hz}``: the crossover frequencies of the stable draws in
    the worst :data:`DECIDING_QUANTILE` of ``|GM|`` (phase crossovers) and of ``|PM|`` (gain
    crossovers) — the crossings the margins' 5 % quantiles are read at (NaN crossings, loops
    without one, are dropped)."""
    out = {}
    for name, fq in (("gm", "gm_freq_hz"), ("pm", "pm_freq_hz")):
        v = report.penalized(f"{name}_db" if name == "gm" else "pm_deg")
        f = np.asarray(getattr(report, fq), dtype=float)
        cut = np.quantile(v, DECIDING_QUANTILE, method="inverted_cdf")
        sel = np.asarray(report.stable, bool) & (v <= cut) & np.isfinite(f)
        out[name] = f[sel]
    return out


def cover_check(report, cover: EvidenceCover, name: str) -> Check:
    """The :class:`~hapid.verdict.Check` of ``report`` (a RobustReport) given what its draws
    cover (module docstring): failed when the draws fail, else not established when the loop
    above the band is not small-gain or a deciding crossing lies outside the band, else
    passed."""
    failed = report.failed_check(name)
    if failed is not None:
        return failed
    lo, hi = cover.measured_hz
    reasons, remedies = [], []
    if not cover.beyond_covered:
        reasons.append(f"above the measured band (to {hi:g} Hz) the loop gain bound is "
                       f"{cover.beyond_loop_gain:.3g} > {cover.kappa:g}: the draws are the model's "
                       "own plant there and do not cover the true loop")  # fmt: skip
        to = (f"measure the FRF to {cover.clear_hz:.3g} Hz"
              if np.isfinite(cover.clear_hz) else "measure the FRF higher")  # fmt: skip
        remedies.append(f"{to}, or lower |g| above {hi:g} Hz to ≤ {cover.g_max:.3g}")
    # above the band a deciding crossing is covered by the small-gain condition (GM ≥ 1/κ
    # there, no gain crossover); below it the draws are an assumption
    f = deciding_frequencies(report)
    for key, label in (("gm", "phase"), ("pm", "gain")):
        below = f[key][f[key] < lo * (1 - BAND_SLACK)]
        if below.size:
            reasons.append(f"the {label} crossovers that decide the {key.upper()} quantile lie "
                           f"below the measured band (from {lo:g} Hz), down to {np.min(below):.3g} Hz")  # fmt: skip
            remedies.append(f"measure the FRF down to {np.min(below) / 1.2:.3g} Hz")
    gap = gap_check(report.quantile("pm_deg", 0.05), report.pm_req_deg, _median(f["pm"]),
                    cover.frequencies_hz)  # fmt: skip
    if gap is not None:
        reasons.append(gap[0])
        remedies.append(gap[1])
    if reasons:
        return Check(Verdict.NOT_ESTABLISHED, reason="; ".join(reasons),
                     remedy="; ".join(dict.fromkeys(remedies)), name=name)  # fmt: skip
    return Check(Verdict.PASSED, name=name)


def deciding_pm_hz(report) -> float:
    """The median gain-crossover frequency (Hz) of the draws that decide the ``|PM|`` 5 %
    quantile (:func:`deciding_frequencies`); NaN when none has one."""
    return _median(deciding_frequencies(report)["pm"])


def _median(f) -> float:
    return float(np.median(f)) if f.size else float("nan")


def gap_check(pm_q05: float, pm_req: float, deciding_hz: float, frequencies_hz,
              *, ratio: float = GAP_RATIO, margin: float = GAP_PM_DEG) -> tuple | None:  # fmt: skip
    """``(reason, remedy)`` when a phase margin is decided in a measurement gap, else ``None``.

    ``pm_q05`` (deg): the 5 % quantile of ``|PM|`` over the draws; ``pm_req`` (deg): the
    requirement; ``deciding_hz``: where the draws that decide it cross over
    (:func:`deciding_pm_hz`); ``frequencies_hz``: the measured frequencies (Hz, increasing).
    The rule fires when ``pm_req ≤ pm_q05 < pm_req + margin`` (below the requirement the
    check has failed already) and ``deciding_hz`` lies strictly between two consecutive
    measured frequencies more than ``ratio`` apart. Outside the measured band the band rules
    of :func:`cover_check` apply instead."""
    f = np.asarray(frequencies_hz, dtype=float)
    if f.size < 2 or not np.isfinite(deciding_hz) or not np.isfinite(pm_q05):
        return None
    if not pm_req <= pm_q05 < pm_req + margin:
        return None
    k = int(np.searchsorted(f, deciding_hz))
    if k == 0 or k == f.size or deciding_hz == f[k]:
        return None
    fa, fb = float(f[k - 1]), float(f[k])
    if fb / fa <= ratio:
        return None
    step = 10.0 ** np.floor(np.log10(fa * (ratio - 1.0)))
    reason = (f"the |PM| 5 % quantile {pm_q05:.3g}° exceeds the required {pm_req:g}° by less "
              f"than {margin:g}° and the gain crossovers that decide it (median "
              f"{deciding_hz:.3g} Hz) lie between the measured {fa:g} and {fb:g} Hz, where the "
              "draws interpolate the loop")  # fmt: skip
    remedy = (f"measure the FRF between {fa:g} and {fb:g} Hz (points at most {ratio:g}× apart, "
              f"e.g. every {step:g} Hz)")  # fmt: skip
    return reason, remedy
