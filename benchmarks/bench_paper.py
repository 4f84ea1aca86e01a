"""`make paper` cold and warm, before and after: two source trees measured the same way, same run.

    python benchmarks/bench_paper.py [--before 336dafc] [--after .] [--repeat 1] [--out out/bench]

What is timed: the whole command `make paper` runs, ``python -m hapid.cli paper --out <dir>
--cache <dir>`` in a new process (interpreter start and imports included), with the source
tree first on ``PYTHONPATH`` and as working directory; the shared venv's packages.

- **cold**: a fresh empty JAX compilation cache (``HAPID_JAX_CACHE``) and a fresh empty stage
  cache (``--cache``): a fresh machine after ``make setup``.
- **warm**: the same command again on both filled caches (best of ``--repeat``).
- **compile cache only**: stage cache emptied, JAX cache kept (every stage recomputed, no
  compilation): what a changed option costs.

"before" is a git revision (default ``336dafc``, the tree issue 13 started from) exported with
``git archive`` into a temporary folder (no worktree is registered, nothing left behind);
"after" is the tree this script lives in (``--after`` another folder). The runs are
interleaved (before cold, after cold, before warm, after warm, …) so both trees see the same
machine load; the load average is recorded with every run. ``run_all.py`` runs this section
in the full suite (``--quick`` skips it: it takes several minutes).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import Section, fs, parser, table  # noqa: E402

BEFORE = "336dafc"


def export_revision(rev: str, dest: Path, repo: Path = HERE.parent) -> str:
    """``git archive`` of ``rev`` into ``dest``; returns the full commit id."""
    sha = subprocess.run(["git", "-C", str(repo), "rev-parse", "--verify", rev + "^{commit}"],
                         capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    dest.mkdir(parents=True, exist_ok=True)
    arch = subprocess.Popen(["git", "-C", str(repo), "archive", sha], stdout=subprocess.PIPE)
    subprocess.run(["tar", "-x", "-C", str(dest)], stdin=arch.stdout, check=True)
    if arch.wait() != 0:
        raise RuntimeError(f"git archive {rev} failed")
    return sha


def tree_label(tree: Path) -> str:
    """Commit of a git tree (+ "dirty" when it has uncommitted changes)."""
    try:
        sha = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
        dirty = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True).stdout.strip()  # fmt: skip
        return sha + (" + uncommitted changes" if dirty else "")
    except (subprocess.CalledProcessError, FileNotFoundError):
        return str(tree)


def paper_once(tree: Path, out: Path, stage_cache: Path, jax_cache: Path) -> dict:
    """One ``hapid paper`` process on ``tree``: wall seconds and the load average before it."""
    env = dict(os.environ, HAPID_JAX_CACHE=str(jax_cache),
               PYTHONPATH=str(tree) + os.pathsep + os.environ.get("PYTHONPATH", ""))  # fmt: skip
    load = os.getloadavg()[0]
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "hapid.cli", "paper", "--out", str(out), "--cache", str(stage_cache)],
                       cwd=tree, env=env, capture_output=True, text=True)  # fmt: skip
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise RuntimeError(f"hapid paper failed in {tree}:\n{p.stderr[-3000:]}")
    stages = [ln for ln in p.stdout.splitlines() if ln.startswith("per stage: ")]
    return {"s": wall, "load": load, "stages": stages[-1][len("per stage: ") :] if stages else ""}


def cold_warm(trees: dict[str, Path], repeat: int = 1, cache_only: bool = True) -> dict:
    """``{name: {"cold": run, "warm": best run, "cache_only": run}}``, runs interleaved."""
    res = {name: {} for name in trees}
    with tempfile.TemporaryDirectory(prefix="hapid-bench-paper-") as d:
        dirs = {name: {k: Path(d) / name / k for k in ("out", "stages", "jax")} for name in trees}
        for name, tree in trees.items():
            res[name]["cold"] = paper_once(tree, **_args(dirs[name]))
        for _ in range(max(1, repeat)):
            for name, tree in trees.items():
                r = paper_once(tree, **_args(dirs[name]))
                if "warm" not in res[name] or r["s"] < res[name]["warm"]["s"]:
                    res[name]["warm"] = r
        if cache_only:
            for name, tree in trees.items():
                shutil.rmtree(dirs[name]["stages"], ignore_errors=True)
                res[name]["cache_only"] = paper_once(tree, **_args(dirs[name]))
    return res


def _args(dd):
    return {"out": dd["out"], "stage_cache": dd["stages"], "jax_cache": dd["jax"]}


def run(quick: bool = False, out: str = "out/bench", before: str = BEFORE, after: str | None = None,
        repeat: int = 1, cache_only: bool = True) -> Section:  # fmt: skip
    sec = Section("make paper: cold and warm, before and after")
    if quick:
        sec.add("(skipped with --quick: several minutes; run `python benchmarks/bench_paper.py`)")
        return sec
    after_tree = Path(after).resolve() if after else HERE.parent
    with tempfile.TemporaryDirectory(prefix="hapid-before-") as d:
        before_tree = Path(d) / "tree"
        sha = export_revision(before, before_tree)
        labels = {"before": f"{before} ({sha[:10]})", "after": tree_label(after_tree)}
        res = cold_warm({"before": before_tree, "after": after_tree}, repeat=repeat,
                        cache_only=cache_only)  # fmt: skip
    rows = []
    for name in ("before", "after"):
        r = res[name]
        rows.append({"tree": f"{name}: {labels[name]}", "cold": fs(r["cold"]["s"]),
                     f"warm (best of {repeat})": fs(r["warm"]["s"]),
                     "compile cache only": fs(r["cache_only"]["s"]) if cache_only else "—",
                     "cold / warm": f"{r['cold']['s'] / r['warm']['s']:.1f}×",
                     "load avg (cold, warm)": f"{r['cold']['load']:.1f}, {r['warm']['load']:.1f}"})  # fmt: skip
    b, a = res["before"], res["after"]
    rows.append({"tree": "**before / after**", "cold": f"{b['cold']['s'] / a['cold']['s']:.2f}×",
                 f"warm (best of {repeat})": f"{b['warm']['s'] / a['warm']['s']:.2f}×",
                 "compile cache only": f"{b['cache_only']['s'] / a['cache_only']['s']:.2f}×" if cache_only else "—",
                 "cold / warm": "", "load avg (cold, warm)": ""})  # fmt: skip
    sec.add("### `make paper` (= `hapid paper`), whole command in a new process\n\n" + table(rows)
            + "\n\ncold: empty JAX compilation cache and empty stage cache; warm: both filled; "
            "compile cache only: stage cache emptied. Runs interleaved before/after; "
            "'before / after' > 1 means the current tree is faster.")  # fmt: skip
    sec.add(
        "per-stage seconds of the cold runs (as `hapid paper` prints them: each stage's "
        "tracing, compilation and run):\n\n"
        + "\n".join(f"- {name}: {res[name]['cold']['stages']}" for name in ("before", "after"))
    )
    sec.goal("make paper cold < 120 s (after)", fs(a["cold"]["s"]), a["cold"]["s"] < 120)
    sec.goal("make paper warm < 20 s (after)", fs(a["warm"]["s"]), a["warm"]["s"] < 20)
    sec.rows["paper"] = {"labels": labels, **res}
    Path(out).mkdir(parents=True, exist_ok=True)
    (Path(out) / "paper_cold_warm.json").write_text(json.dumps(sec.rows["paper"], indent=1))
    return sec


def main(argv=None):
    from _common import header

    ap = parser(__doc__)
    ap.add_argument("--before", default=BEFORE, help=f"git revision of 'before' (default {BEFORE})")
    ap.add_argument("--after", default=None, help="source tree of 'after' (default: this tree)")
    ap.add_argument("--repeat", type=int, default=1, help="warm runs per tree (best is kept)")
    ap.add_argument(
        "--no-cache-only", action="store_true", help="skip the 'compile cache only' runs"
    )
    args = ap.parse_args(argv)
    print(header(__doc__.strip().splitlines()[0]), flush=True)
    t = time.perf_counter()
    sec = run(args.quick, args.out, args.before, args.after, args.repeat, not args.no_cache_only)
    print(f"\ngoals (as measured):\n{table(sec.goals)}" if sec.goals else "")
    print(f"({sec.title}: {time.perf_counter() - t:.0f} s)")
    return sec


if __name__ == "__main__":
    main()
