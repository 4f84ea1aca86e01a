"""The three-valued verdict of a requirement check: passed, failed or not established.

Every place that checks a requirement (``hapid robust``, the tuner's certificate and re-check,
``hapid analyze`` with requirements, ``hapid design``) reports a :class:`Check`. A check is
``passed`` only when the evidence covers every frequency the requirement depends on; when it
does not, the check is ``not established`` and says why and what would establish it (measure
to a higher frequency, lower the gain above some frequency), never ``passed`` beside a warning.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Verdict(enum.StrEnum):
    """Outcome of a requirement check. The value is the word the CLI and JSON files use."""

    PASSED = "passed"
    FAILED = "failed"
    NOT_ESTABLISHED = "not established"


_RANK = {Verdict.PASSED: 0, Verdict.NOT_ESTABLISHED: 1, Verdict.FAILED: 2}


@dataclass(frozen=True)
class Check:
    """One requirement check.

    Attributes:
        verdict: passed / failed / not established.
        reason: why it is not passed (empty when passed).
        remedy: what would establish it (only for not established; empty otherwise).
        name: what was checked, e.g. ``"GM >= 6 dB, PM >= 30 deg"``.
    """

    verdict: Verdict
    reason: str = ""
    remedy: str = ""
    name: str = ""

    def __post_init__(self):
        object.__setattr__(self, "verdict", Verdict(self.verdict))
        if self.verdict is Verdict.PASSED and (self.reason or self.remedy):
            raise ValueError("a passed check carries no reason or remedy")
        if self.verdict is Verdict.NOT_ESTABLISHED and not self.reason:
            raise ValueError("a check that is not established must say why (reason)")

    @property
    def ok(self) -> bool:
        """True only when passed."""
        return self.verdict is Verdict.PASSED

    @property
    def status(self) -> Verdict:
        return self.verdict

    def summary(self) -> dict:
        """Strict-JSON dict: ``verdict`` (str), ``reason``, ``remedy``, ``name``, and
        ``status`` (the verdict again, as every result's summary has it) and ``ok``."""
        return {"verdict": self.verdict.value, "reason": self.reason, "remedy": self.remedy,
                "name": self.name, "status": self.verdict.value, "ok": self.ok}  # fmt: skip

    def line(self) -> str:
        """One line for the CLI, verdict first: ``passed``, ``failed: …``, ``not established: … (…)``."""
        head = f"{self.name}: {self.verdict.value}" if self.name else self.verdict.value
        if self.verdict is Verdict.PASSED:
            return head
        tail = f" — {self.remedy}" if self.remedy else ""
        return f"{head}: {self.reason}{tail}"


def combine(verdicts) -> Verdict:
    """The combined verdict of an iterable of :class:`Verdict`: failed if any failed, else not
    established if any is, else passed. Raises ``ValueError`` when it is empty."""
    verdicts = list(verdicts)
    if not verdicts:
        raise ValueError("combine() needs at least one verdict")
    return max(verdicts, key=_RANK.__getitem__)


def worst(*checks: Check) -> Verdict:
    """The combined verdict of ``checks`` (:func:`combine` of their verdicts)."""
    if not checks:
        raise ValueError("worst() needs at least one check")
    return combine(c.verdict for c in checks)
