"""``hapid design``: from a lab recording to a checked controller and a report, in one command.

:func:`run_design` runs the stages of the single commands (``frf``, ``fit`` WLS + positize /
NLS / ML, ``posterior``, ``robust``, ``tune``) on :mod:`hapid._stages`' cached graph
(:mod:`hapid.design._graph`), then writes their files, the figures (PNG and PDF),
``report.json`` and a self-contained ``report.html`` with the verdict table
(:class:`hapid.verdict.Check` per requirement). Returns a :class:`DesignReport`.

Names load on first use (PEP 562): the command line builds its parser from :data:`STAGES`
and :class:`DesignOptions` (:mod:`._commands`, light) without importing the stages behind
:func:`run_design` (the tuner, the posterior, emcee and scipy.stats: ≈ 2.4 s that every
other ``hapid`` command paid at start-up).
"""

from .._lazy import lazy_names as _lazy_names

_NAMES = {
    "PAIR_ONLY": "_commands",
    "STAGES": "_commands",
    "DesignOptions": "_commands",
    "commands": "_commands",
    "DesignReport": "_design",
    "DesignStatus": "_design",
    "delivered": "_design",
    "run_design": "_design",
    "EXPECTED_S": "_graph",
    "check_of": "_verdict",
}
__all__ = list(_NAMES)

__getattr__, __dir__ = _lazy_names(__name__, _NAMES)
