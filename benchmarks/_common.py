"""Shared benchmark helpers: machine header, timing, tables, the section record, CLI.

Every ``bench_*.py`` exposes ``run(quick=False, out="out/bench") -> Section`` (what
``run_all.py`` collects) and ``main(argv)`` (runnable on its own: prints the header and the
section's markdown). Times are wall-clock seconds after a warm-up call (compile excluded)
unless a column says "compile" or "cold".
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import time
from importlib import metadata
from pathlib import Path

PACKAGES = ("hapid", "jax", "jaxlib", "numpy", "scipy", "optimistix", "lineax", "jaxopt",
            "equinox", "emcee", "scikit-rf")  # fmt: skip


def versions() -> str:
    pk = []
    for name in PACKAGES:
        try:
            pk.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            pass
    return ", ".join(pk)


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return (f"{platform.machine()}, {os.cpu_count()} cores ({cpu}); {platform.system()} "
            f"{platform.release()}; python {platform.python_version()}; load average {load}")  # fmt: skip


def header(title: str) -> str:
    return "\n".join(
        [
            f"# {title}",
            f"machine: {machine()}",
            f"versions: {versions()}",
            f"date: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}",
        ]
    )


def _block(x):
    try:
        import jax

        return jax.block_until_ready(x)
    except Exception:  # noqa: BLE001  (non-JAX output)
        return x


def timeit(fn, *, repeat: int = 5, number: int = 1) -> float:
    """Best-of-``repeat`` wall time of ``number`` calls, in seconds per call (no warm-up)."""
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            _block(fn())
        best = min(best, (time.perf_counter() - t) / number)
    return best


def measure(fn, *, repeat: int = 3, number: int = 1):
    """``(output, first call s, best s per call after it)``; blocks on JAX outputs.

    Best-of rather than median: on a shared machine the minimum is the least perturbed
    estimate of what the code costs.

    The first call includes tracing and compilation (or a persistent-cache load);
    ``first − best`` is what the tables call compile time.
    """
    t = time.perf_counter()
    out = _block(fn())
    first = time.perf_counter() - t
    runs = []
    for _ in range(max(repeat, 1)):
        t = time.perf_counter()
        for _ in range(number):
            out = _block(fn())
        runs.append((time.perf_counter() - t) / number)
    return out, first, min(runs)


def table(rows: list[dict]) -> str:
    """A markdown table from a list of dicts (keys of the first row are the columns)."""
    if not rows:
        return "(no rows)"
    keys = list(rows[0])
    w = {k: max(len(k), *(len(str(r.get(k, ""))) for r in rows)) for k in keys}
    out = ["| " + " | ".join(k.ljust(w[k]) for k in keys) + " |",
           "|" + "|".join("-" * (w[k] + 2) for k in keys) + "|"]  # fmt: skip
    for r in rows:
        out.append("| " + " | ".join(str(r.get(k, "")).ljust(w[k]) for k in keys) + " |")
    return "\n".join(out)


def fs(x: float) -> str:
    """A duration, readable: 1.23 s, 45.6 ms, 7.8 µs."""
    if x != x:  # nan
        return "nan"
    if x >= 1:
        return f"{x:.2f} s"
    if x >= 1e-3:
        return f"{1e3 * x:.3g} ms"
    return f"{1e6 * x:.3g} µs"


def fg(x, p: int = 3) -> str:
    return f"{x:.{p}g}" if isinstance(x, float) else str(x)


@dataclasses.dataclass
class Section:
    """One benchmark's contribution to the report."""

    title: str
    markdown: str = ""
    figures: list[str] = dataclasses.field(default_factory=list)  # paths (absolute or rel.)
    goals: list[dict] = dataclasses.field(default_factory=list)  # goal, measured, met
    rows: dict = dataclasses.field(default_factory=dict)  # raw numbers, for reuse
    seconds: float = 0.0

    def add(self, text: str) -> None:
        self.markdown += text.rstrip("\n") + "\n\n"
        print(text, flush=True)

    def goal(self, goal: str, measured: str, met) -> None:
        self.goals.append({"goal": goal, "measured": measured,
                           "met": "—" if met is None else ("yes" if met else "**no**")})  # fmt: skip


def parser(doc: str) -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true", help="reduced sizes (a few minutes)")
    ap.add_argument("--out", default="out/bench", help="folder for figures (default out/bench)")
    return ap


def standalone(run, doc: str, argv=None) -> Section:
    """``main(argv)`` of a bench script: parse --quick/--out, print header, run."""
    args = parser(doc).parse_args(argv)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    print(header(doc.strip().splitlines()[0]), flush=True)
    t = time.perf_counter()
    sec = run(quick=args.quick, out=args.out)
    sec.seconds = time.perf_counter() - t
    if sec.goals:
        print("\ngoals (as measured):\n" + table(sec.goals))
    for f in sec.figures:
        print(f"figure: {f}")
    print(f"({sec.title}: {sec.seconds:.0f} s)")
    return sec


# ---- issue-13 goals table: the contract with run_all.py (benchmarks/README.md) ------------

ISSUE_ROWS = (  # (id, work, goal, script that writes the row)
    ("loop_analysis", "loop analysis: Nyquist verdict + σ̄(T − I) bandwidth + loci margins",
     "≥ 30× numpy, warm", "bench_fast"),
    ("robust_check", "robust check, 1000 draws × 1000 frequencies",
     "≤ 2 s warm, same verdicts as the per-plant analysis", "bench_fast"),
    ("wls_bound", "batched WLS vs the memory-bandwidth bound",
     "≥ 50 % of the bound measured in the same run", "bench_throughput"),
    ("nls_scipy", "NLS (LM), paper protocol, equal final cost, vs scipy least_squares (exact Jacobian)",
     "≥ 10×", "bench_pipeline"),
    ("nls_batch", "fit_nls_batch, B = 64, vs a Python loop of fit_nls", "≥ 4× the loop",
     "bench_throughput"),
    ("paper_pipeline", "paper pipeline end to end (simulate → FRF → fits → analysis) vs numpy/scipy",
     "≥ 10×", "bench_pipeline"),
)  # fmt: skip
ISSUE_GOAL = {rid: goal for rid, _, goal, _ in ISSUE_ROWS}  # the issue's wording of each goal
ROW_KEYS = ("id", "work", "reference", "reference_s", "hapid_s", "ratio", "goal", "met", "reason")


def write_goal_rows(out: str, script: str, rows: list[dict], quick: bool) -> Path:
    """Write ``<out>/goals/<script>.json``: this script's rows of the issue-13 goals table.

    Each row has :data:`ROW_KEYS` (``None`` where a value does not exist; ``ratio`` =
    ``reference_s / hapid_s``); ``run_all.py`` assembles the table from these files."""
    import json

    ids = {row[0] for row in ISSUE_ROWS}
    for r in rows:
        missing = [k for k in ROW_KEYS if k not in r]
        if missing or r["id"] not in ids:
            raise ValueError(
                f"goal row {r.get('id')!r}: missing {missing} or unknown id (known: {sorted(ids)})"
            )
    path = Path(out) / "goals" / f"{script}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"script": script, "quick": bool(quick), "rows": rows}, indent=1))
    return path
