"""The CLI's lines for three-valued verdicts (:class:`hapid.verdict.Check`), verdict first."""

from __future__ import annotations


def check_line(ck) -> str:
    """One line of a :class:`hapid.verdict.Check`, the verdict first:
    ``NOT ESTABLISHED — GM ≥ 6 dB, PM ≥ 30° (loop): reason. To establish it: remedy``."""
    line = f"{ck.verdict.value.upper()} — {ck.name}"
    if ck.reason:
        line += f": {ck.reason}"
    if ck.remedy:
        line += f". To establish it: {ck.remedy}"
    return line


def verdict_lines(res) -> list[str]:
    """The verdict of each batch of a :class:`hapid.robust.RobustResult`, one line each,
    verdict first: ``posterior: not established: … — measure …``."""
    out = []
    for batch in ("posterior", "device"):
        sm = res.numbers().get(batch)
        if sm is None:
            continue
        line = f"{batch}: {sm['verdict'].upper()} — {sm['check']}"
        if sm["reason"]:
            line += f": {sm['reason']}"
        if sm["remedy"]:
            line += f". To establish it: {sm['remedy']}"
        out.append(line)
    return out
