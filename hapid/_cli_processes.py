"""``--processes`` of ``hapid sweep`` and ``hapid robust``: its help text and which process
reports (:mod:`hapid._distributed` is imported only when a command asks)."""

from __future__ import annotations

from ._distributed import is_main

_PROCESSES_HELP = (
    "split the work over N local processes joined by jax.distributed (results "
    "identical to one process); on a cluster set HAPID_COORDINATOR, "
    "HAPID_NUM_PROCESSES, HAPID_PROCESS_ID instead (docs/distributed.md); default: one process"
)


def _is_main() -> bool:
    return is_main()
