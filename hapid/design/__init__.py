"""``hapid design``: from a lab recording to a checked controller and a report, in one command.

:func:`run_design` runs the stages of the single commands (``frf``, ``fit`` WLS + positize /
NLS / ML, ``posterior``, ``robust``, ``tune``) on :mod:`hapid._stages`' cached graph
(:mod:`hapid.design._graph`), then writes their files, the figures (PNG and PDF),
``report.json`` and a self-contained ``report.html`` with the verdict table
(:class:`hapid.verdict.Check` per requirement). Returns a :class:`DesignReport`.
"""

from ._commands import PAIR_ONLY as PAIR_ONLY
from ._commands import STAGES as STAGES
from ._commands import DesignOptions as DesignOptions
from ._commands import commands as commands
from ._design import DesignReport as DesignReport
from ._design import DesignStatus as DesignStatus
from ._design import delivered as delivered
from ._design import run_design as run_design
from ._graph import EXPECTED_S as EXPECTED_S
from ._verdict import check_of as check_of
