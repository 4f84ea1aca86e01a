"""Paper reproduction, cold against warm, as a whole command (`hapid paper`).

    python benchmarks/bench_paper.py [--out out/bench]

Cold: an empty JAX compilation cache and an empty stage cache (fresh temp folders), i.e. a
fresh machine after `make setup`. Warm: the same command again with both caches filled; then
with the compile cache only. Goals (issue): cold < 2 min, warm < 20 s on the 2-core machine.
``run_all.py`` runs this as part of ``bench_compile.py`` (full run only).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Section, standalone  # noqa: E402
from bench_compile import paper_cold_warm  # noqa: E402


def run(quick: bool = False, out: str = "out/bench") -> Section:
    sec = Section("Paper reproduction: cold vs warm")
    paper_cold_warm(sec, cache_only=True)
    return sec


def main(argv=None):
    return standalone(run, __doc__, argv)


if __name__ == "__main__":
    main()
