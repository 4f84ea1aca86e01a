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
    """The paper g on ``model``'s controller: the robust report's own three-valued check
    (:attr:`hapid.uncertainty.RobustReport.check`: loop draws, coverage of the measured band),
    named for the design's table."""
    c = report.check
    return Check(c.verdict, reason=c.reason, remedy=c.remedy,
                 name=f"paper g, {LABELS.get(model, model)} model: {REQUIREMENT}")  # fmt: skip


def tuned_row(tune: dict) -> dict:
    """The re-check row of the design the tuner returned."""
    table = tune["info"].get("table") or {}
    return table.get("returned") or table.get("start" if tune["kept_start"] else "tuned") or {}


def tuned_check(tune: dict, quantile: float = 0.975) -> Check:
    """The returned g: the tuner's own three-valued check (``hapid tune``'s verdict, stored in
    the design info); from the re-check row (held-out draws at the chance level ``quantile``,
    the FRF certificate) when the info has no verdict."""
    info = tune["info"]
    name = f"{TUNED}, NLS model: margins on held-out draws and the FRF certificate"
    if info.get("verdict"):
        return Check(info["verdict"], reason=info.get("reason", ""),
                     remedy=info.get("remedy", ""), name=name)  # fmt: skip
    row = tuned_row(tune)
    frac = row.get("posterior_frac_meeting_margins")
    passed = bool(row.get("posterior_passed", True)) and (frac is None or frac >= quantile - 1e-9)
    reasons = []
    if not passed:
        reasons.append(f"held-out loop draws: P(stable) {row.get('posterior_p_stable', float('nan')):.3f}, "
                       f"{100 * (frac if frac is not None else float('nan')):.1f} % meet GM ≥ 6 dB, "
                       f"PM ≥ 30° (required {100 * quantile:.1f} %)")  # fmt: skip
    warn = uncertified_warning(row)
    return check_of(name, passed, reasons, warn.removeprefix("WARNING: "),
                    "measure the FRF densely around the crossover and tune on it")  # fmt: skip
