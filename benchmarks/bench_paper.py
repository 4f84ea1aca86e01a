"""Paper reproduction, cold against warm, as a whole command (`hapid paper`).

    python benchmarks/bench_paper.py

Cold: an empty JAX compilation cache and an empty stage cache (fresh temp folders), i.e. a
fresh machine after `make setup`. Warm: the same command again with both caches filled.
Goals (issue): cold < 2 min, warm < 20 s on the 2-core machine.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _common import header, table  # noqa: E402


def run(out, cache, jax_cache):
    env = dict(os.environ, HAPID_JAX_CACHE=jax_cache)
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "hapid.cli", "paper", "--out", out, "--cache", cache],
                         env=env, capture_output=True, text=True)  # fmt: skip
    dt = time.perf_counter() - t
    if res.returncode != 0:
        raise SystemExit(res.stderr[-3000:])
    return dt


def main():
    print(header("paper reproduction: cold vs warm"))
    with tempfile.TemporaryDirectory() as d:
        out, cache, jc = (str(Path(d) / x) for x in ("out", "stages", "jax"))
        cold = run(out, cache, jc)
        warm = run(out, cache, jc)
        os.system(f"rm -rf {cache}")
        compile_warm = run(out, cache, jc)
    print(table([
        {"run": "cold (no compile cache, no stage cache)", "time (s)": f"{cold:.1f}", "goal": "< 120"},
        {"run": "warm (both caches)", "time (s)": f"{warm:.1f}", "goal": "< 20"},
        {"run": "compile cache only (stages recomputed)", "time (s)": f"{compile_warm:.1f}", "goal": "—"},
    ]))  # fmt: skip
    print(f"cold / warm = {cold / warm:.1f}×")


if __name__ == "__main__":
    main()
