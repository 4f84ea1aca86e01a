"""The requirement check of one analysed loop (``hapid analyze --gm-db/--pm-deg``).

A loop on a simulated device's true plant covers every frequency: the check is ``passed`` or
``failed`` (Nyquist verdict, then ``|GM|``, ``|PM|`` — the margin sign convention of
:mod:`hapid.uncertainty._robust`). A loop on a measured FRF covers only the FRF's band
``[f₁, f_e]``: the Nyquist count runs over that band alone, so a verdict needs the loop to be
small above it (``σ̄(L(f_e)) ≤ κ``, the small-gain level of :mod:`hapid.tune._evidence`) —
else the check is ``not established`` (measure the FRF higher). A failure the FRF shows
(margins below the requirement at measured frequencies, a resolved unstable count) is
``failed``.
"""

from __future__ import annotations

import numpy as np

from ._constants import KAPPA
from .verdict import Check, Verdict


def loop_label(ts: float | None) -> str:
    """``"continuous-time controller"`` or ``"controller sampled at F Hz"``."""
    return "continuous-time controller" if ts is None else f"controller sampled at {1.0 / ts:g} Hz"


def margin_words(gm_db: float, pm_deg: float) -> str:
    """``GM 3.1 dB, PM 24.7°`` from signed margins, each negative one explained: a stable
    loop whose locus crosses the negative real axis left of −1 (``GM < 0``) is destabilized
    by a gain *decrease* of ``|GM|``; a negative PM, by a phase *lead* of ``|PM|``."""
    parts = []
    for v, unit, what, how in ((gm_db, " dB", "GM", "a gain decrease"),
                               (pm_deg, "°", "PM", "a phase lead")):  # fmt: skip
        if np.isfinite(v) and v < 0:
            parts.append(f"{what} {abs(v):.1f}{unit} (signed {v:.1f}{unit}: the locus crosses "
                         f"beyond −1, conditionally stable — {how} of {abs(v):.1f}{unit} "
                         "destabilizes it)")  # fmt: skip
        else:
            parts.append(f"{what} {v:.1f}{unit}")
    return ", ".join(parts)


def loop_check(summary: dict, *, gm_db: float, pm_deg: float, ts: float | None,
               frf_band_hz=None, top_loop_gain: float | None = None) -> Check:  # fmt: skip
    """The :class:`~hapid.verdict.Check` of a loop's numbers (:meth:`LoopMetrics.numbers`)
    against ``gm_db`` / ``pm_deg``. ``frf_band_hz`` ``(f₁, f_e)`` and ``top_loop_gain``
    (``σ̄(L)`` at ``f_e``): the plant is a measured FRF (module docstring); ``None``: a
    simulated plant on a full grid."""
    name = f"GM ≥ {gm_db:g} dB, PM ≥ {pm_deg:g}° ({loop_label(ts)})"
    resolved = bool(summary.get("nyquist_resolved", True))
    small_top = frf_band_hz is None or (top_loop_gain is not None and top_loop_gain <= KAPPA)
    if summary["stable"]:
        gm, pm = abs(float(summary["gm_db"])), abs(float(summary["pm_deg"]))
        short = ([f"|GM| {gm:.2f} dB < {gm_db:g} dB"] if gm < gm_db else []) + (
            [f"|PM| {pm:.1f}° < {pm_deg:g}°"] if pm < pm_deg else [])  # fmt: skip
        if short:
            return Check(Verdict.FAILED, reason="; ".join(short), name=name)
    elif resolved and small_top:
        return Check(Verdict.FAILED, reason="the closed loop is not stable (generalized Nyquist)",
                     name=name)  # fmt: skip
    why, fix = [], []
    if not resolved:
        why.append("the Nyquist count is not resolved on the grid")
        fix.append("a denser grid (measure the FRF densely around the crossover)")
    if not small_top:
        lo, hi = frf_band_hz
        why.append(f"the FRF covers {lo:g}–{hi:g} Hz only and the loop gain at {hi:g} Hz is "
                   f"{top_loop_gain:.3g} > {KAPPA:g}: the Nyquist count and the margins above "
                   "it are not known")  # fmt: skip
        fix.append(f"measure the FRF above {hi:g} Hz, up to where the loop gain is below {KAPPA:g}")
    if why:
        return Check(Verdict.NOT_ESTABLISHED, reason="; ".join(why), remedy="; ".join(fix),
                     name=name)  # fmt: skip
    return Check(Verdict.PASSED, name=name)
