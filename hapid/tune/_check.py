"""The three-valued verdict of a tuned design: its re-check row and certificate as one Check.

A design's re-check (:func:`hapid.tune._validate.table_row`) and evidence certificate
(:func:`hapid.tune._evidence.certificate`) say, per source of evidence, whether the
requirements hold. :func:`design_check` turns the returned design's row into one
:class:`hapid.verdict.Check`:

- **failed** when any evidence shows a failure: the nominal loop (model's own plant) is not
  stable; the measured loop's loci come within ``FRF_FLOOR`` of −1 at a measured frequency;
  fewer held-out draws than the chance level meet the margins; the simulated true plant
  (``--device``) is unstable or misses GM/PM; a held-out device variant fails;
- **not established** when nothing failed but the evidence does not cover the loop: the loop
  gain above the measured band exceeds κ (the draws are the model's own plant there), the
  held-out draws' phase margin is decided in a measurement gap by less than
  :data:`~hapid.defaults.GAP_PM_DEG` (:func:`hapid.uncertainty._cover.gap_check`; without a
  true plant to settle it), or there is neither a measured FRF nor a simulated device
  (parameter draws only: the model class's uncertainty, not the plant's);
- **passed** otherwise.

The check's name states the requirements and the loop (continuous-time controller, or the
rate the controller is sampled at): the verdict holds for that loop.
"""

from __future__ import annotations

import numpy as np

from .._analyze_check import loop_label  # noqa: F401  (re-exported)
from .._constants import KAPPA
from ..uncertainty._cover import gap_check
from ..verdict import Check, Verdict

FRF_FLOOR = 0.5  # min |1 + λ_i| ≥ 0.5 on the measured loop ⇒ loci GM ≥ 6 dB, PM ≥ 29° there


def design_check(row: dict, *, gm_db: float, pm_deg: float, quantile: float, ts=None,
                 g_max: float | None = None, frequencies_hz=()) -> Check:  # fmt: skip
    """The :class:`~hapid.verdict.Check` of a design's re-check ``row`` (module docstring).
    ``quantile``: the chance level the held-out draws must meet; ``ts``: the controller's
    sampling period (``None``: continuous), named in the check; ``g_max``: the largest
    ``|g|`` above the evidence the small-gain condition allows (for the remedy);
    ``frequencies_hz``: the measured FRF's frequencies (Hz), for the gap rule (empty: not
    applied)."""
    name = f"GM ≥ {gm_db:g} dB, PM ≥ {pm_deg:g}° ({loop_label(ts)})"
    fail = []
    if row.get("nominal_stable") is False:
        fail.append("the loop on the model's own plant is not stable")
    ld = row.get("frf_min_loci_distance")
    if ld is not None and ld < FRF_FLOOR:
        fail.append(
            f"on the measured FRF the loci come within {ld:.3g} of −1 (floor {FRF_FLOOR:g})"
        )
    frac = row.get("posterior_frac_meeting_margins")
    if frac is not None and frac < quantile - 1e-9:
        fail.append(f"{100 * frac:.1f} % of held-out draws meet the margins (required "
                    f"{100 * quantile:.1f} %)")  # fmt: skip
    if "true_stable" in row:
        if not row["true_stable"]:
            fail.append("the true plant's loop is not stable")
        elif abs(row["true_gm_db"]) < gm_db or abs(row["true_pm_deg"]) < pm_deg:
            fail.append(f"on the true plant GM {row['true_gm_db']:.1f} dB, PM "
                        f"{row['true_pm_deg']:.1f}°")  # fmt: skip
    if row.get("variants_passed") is False:
        fail.append("a held-out device variant misses the requirements")
    if fail:
        return Check(Verdict.FAILED, reason="; ".join(fail), name=name)
    bg = row.get("beyond_loop_gain")
    if bg is not None and bg > KAPPA + 1e-9:
        fe = row.get("evidence_hz", float("nan"))
        lower = f" to ≤ {g_max:.3g}" if g_max is not None and np.isfinite(g_max) else ""
        return Check(Verdict.NOT_ESTABLISHED, name=name,
                     reason=f"the loop gain above the measured band (to {fe:.3g} Hz) is {bg:.3g} > "
                     "0.5: the draws are the model's own plant there and do not cover the loop",
                     remedy=f"measure the FRF higher, or lower |g| above {fe:.3g} Hz{lower}")  # fmt: skip
    gap = None if "true_stable" in row else gap_check(
        row.get("posterior_pm_deg_q05", float("nan")), pm_deg,
        row.get("posterior_pm_deciding_hz", float("nan")), frequencies_hz)  # fmt: skip
    if gap is not None:
        return Check(Verdict.NOT_ESTABLISHED, name=name, reason=gap[0], remedy=gap[1])
    if bg is None and "true_stable" not in row:
        return Check(Verdict.NOT_ESTABLISHED, name=name,
                     reason="no measured FRF and no device: the draws cover the model class's "
                     "parameter uncertainty only",
                     remedy="give the measured FRF (--frf) or a device (--device)")  # fmt: skip
    return Check(Verdict.PASSED, name=name)
