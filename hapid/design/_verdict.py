"""The verdict table of a design: one :class:`hapid.verdict.Check` per requirement check.

:func:`check_of` is the one place that turns a report's fields into a three-valued check
(``passed`` with a coverage warning → ``not established``, the warning as the reason).
"""

from __future__ import annotations

from .._cli_kw import uncertified_warning
from ..verdict import Check, Verdict
from ._figures import LABELS

TUNED = "tuned g"  # the name of the tuned g's check starts with this
REQUIREMENT = "P(stable) ≥ 0.95, |GM| ≥ 6 dB, |PM| ≥ 30° on loop draws"


def check_of(name: str, passed: bool, reasons, warning: str = "", remedy: str = "") -> Check:
    """The check of a report: ``failed`` (``reasons`` joined) unless ``passed``; a passed
    report with a coverage ``warning`` is ``not established`` (``warning`` the reason,
    ``remedy`` what would establish it); else ``passed``."""
    if not passed:
        return Check(Verdict.FAILED, reason="; ".join(reasons) or "requirement not met", name=name)
    if warning:
        return Check(Verdict.NOT_ESTABLISHED, reason=warning, remedy=remedy, name=name)
    return Check(Verdict.PASSED, name=name)


def robust_check(model: str, report, info: dict) -> Check:
    """The paper g on ``model``'s controller: the robust report and its loop draws' coverage."""
    s = report.summary()
    warn = remedy = ""
    if not info.get("beyond_covered", True):
        hi = info["measured_hz"][1]
        warn = (f"the loop gain above the measured {hi:g} Hz is {info['beyond_loop_gain']:.3g} "
                "> 0.5: the draws there are the model's own plant, so they do not cover the loop")  # fmt: skip
        remedy = f"measure the FRF above {hi:g} Hz, or lower g's gain above {hi:g} Hz"
    return check_of(f"paper g, {LABELS.get(model, model)} model: {REQUIREMENT}", s["passed"],
                    s["reasons"], warn, remedy)  # fmt: skip


def tuned_row(tune: dict) -> dict:
    """The re-check row of the design the tuner returned."""
    table = tune["info"].get("table") or {}
    return table.get("returned") or table.get("start" if tune["kept_start"] else "tuned") or {}


def tuned_check(tune: dict, quantile: float = 0.975) -> Check:
    """The returned g: its held-out draws' margins (the chance level ``quantile``, ``hapid
    tune``'s default) and its certificate on the measured FRF."""
    row = tuned_row(tune)
    frac = row.get("posterior_frac_meeting_margins")
    passed = bool(row.get("posterior_passed", True)) and (frac is None or frac >= quantile - 1e-9)
    reasons = []
    if not passed:
        reasons.append(f"held-out loop draws: P(stable) {row.get('posterior_p_stable', float('nan')):.3f}, "
                       f"{100 * (frac if frac is not None else float('nan')):.1f} % meet GM ≥ 6 dB, "
                       f"PM ≥ 30° (required {100 * quantile:.1f} %)")  # fmt: skip
    warn = uncertified_warning(row)
    return check_of(f"{TUNED}, NLS model: margins on held-out draws and the FRF certificate",
                    passed, reasons, warn.removeprefix("WARNING: "),
                    "measure the FRF densely around the crossover and tune on it")  # fmt: skip
