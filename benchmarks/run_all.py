"""Run the whole hapid benchmark suite and write a markdown report with figures.

    .venv/bin/python benchmarks/run_all.py [--quick] [--out out/bench] [--only fit,throughput]

(``make bench`` runs it with the defaults.) Writes ``<out>/report.md`` (rewritten after every
section, so an interrupted run keeps what it measured) and the figures next to it. Each
section is one ``benchmarks/bench_*.py`` script, which also runs on its own. Goals are
reported as measured, never asserted: the command fails only if a script crashes.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import ISSUE_ROWS, Section, fs, header, table  # noqa: E402

import hapid  # noqa: E402,F401  (before any JAX computation: XLA flags, float64)

# (key, module); order = report order
SUITE = [
    ("fast", "bench_fast"),
    ("fit", "bench_fit"),
    ("throughput", "bench_throughput"),
    ("compile", "bench_compile"),
    ("pipeline", "bench_pipeline"),
    ("experiment", "bench_experiment"),
    ("control", "bench_control"),
    ("tune", "bench_tune"),
    ("uncertainty", "bench_uncertainty"),
    ("paper", "bench_paper"),
]


def _rel(path: str, out: Path) -> str:
    p = Path(path).resolve()
    try:
        return str(p.relative_to(out.resolve()))
    except ValueError:
        return str(p)


def _num(x, fmt) -> str:
    return "—" if x is None or not isinstance(x, int | float) else fmt(float(x))


# fallback while a script writes no JSON row: its Section.goal line, matched by these prefixes
_GOAL_PREFIX = {"loop_analysis": ("loop analysis",), "robust_check": ("robust check",),
                "wls_bound": ("batched wls",), "nls_scipy": ("nls (lm)",),
                "nls_batch": ("fit_nls_batch",), "paper_pipeline": ("paper pipeline",)}  # fmt: skip


def _goal_line(rid: str, sections) -> dict | None:
    hits = [g for s in sections for g in s.goals
            if g["goal"].lower().startswith(_GOAL_PREFIX[rid])]  # fmt: skip
    if rid == "nls_scipy":  # the exact-Jacobian comparison, as the issue states it
        hits = [g for g in hits if "exact" in g["goal"] or "analytic" in g["goal"]] or hits
    return hits[-1] if hits else None


def issue_table(out: Path, since: float, sections=()) -> list[dict]:
    """The six rows of the issue-13 table from ``<out>/goals/*.json`` written since ``since``
    (benchmarks/README.md, "Goals table contract"). A row no script wrote in this run is
    taken from the matching ``Section.goal`` line of this run's ``sections`` (its measured
    text in the ratio column), else shown as not measured."""
    fresh, stale, bad = {}, set(), []
    for f in sorted((out / "goals").glob("*.json")):
        try:
            d = json.loads(f.read_text())
            rows = list(d["rows"])
        except (OSError, ValueError, KeyError, TypeError):
            bad.append(f.name)
            continue
        for r in rows:
            if not isinstance(r, dict) or "id" not in r:
                bad.append(f.name)
            elif f.stat().st_mtime >= since:
                # a row's own "quick" (extra key) says whether its sizes were reduced
                fresh[r["id"]] = r | {"_quick": r.get("quick", d.get("quick"))}
            else:
                stale.add(r["id"])
    table_rows = []
    for rid, work, goal, script in ISSUE_ROWS:
        r = fresh.get(rid)
        g = None if r is not None else _goal_line(rid, sections)
        if g is not None:
            table_rows.append({"work": work, "numpy / scipy": "(in ratio)", "hapid": "(in ratio)",
                               "ratio": g["measured"].replace("|", "/"), "goal": g["goal"],
                               "met": g["met"], "reason": f"from {script}.py's goal line (no goals "
                               "JSON row written)"})  # fmt: skip
            continue
        if r is None:
            why = f"{script}.py wrote no row `{rid}` in this run"
            if rid in stale:
                why += " (a row from an earlier run exists; ignored)"
            if bad:
                why += f"; unreadable: {', '.join(sorted(set(bad)))}"
            table_rows.append({"work": work, "numpy / scipy": "—", "hapid": "—", "ratio": "—",
                               "goal": goal, "met": "not measured", "reason": why})  # fmt: skip
            continue
        ratio = r.get("ratio")
        pct = rid == "wls_bound"  # a fraction of the bound, not a speed-up
        rtxt = _num(ratio, lambda x, pct=pct: f"{100 * x:.1f} % of bound" if pct else f"{x:.3g}×")
        ref = _num(r.get("reference_s"), fs)
        if r.get("reference"):
            ref += f" ({r['reference']})"
        met = r.get("met")
        table_rows.append({
            "work": str(r.get("work") or work) + (" (--quick sizes)" if r.get("_quick") else ""),
            "numpy / scipy": ref, "hapid": _num(r.get("hapid_s"), fs), "ratio": rtxt,
            "goal": str(r.get("goal") or goal),
            "met": "—" if met is None else ("yes" if met else "**no**"),
            "reason": str(r.get("reason") or "").replace("|", "/").replace("\n", " "),
        })  # fmt: skip
    return table_rows


def write_report(
    out: Path, sections: list[Section], head: str, argv, total: float, pending, since: float
) -> Path:
    goals = [dict(section=s.title, **g) for s in sections for g in s.goals]
    issue = issue_table(out, since, sections)
    lines = [head.replace("# hapid benchmarks", "# hapid benchmark report", 1), "",
             f"command: `{' '.join([Path(sys.executable).name, 'benchmarks/run_all.py', *argv])}`; "
             f"suite wall time {total:.0f} s" + (f"; **not yet run: {', '.join(pending)}**" if pending else ""),
             "",
             "All times are wall-clock on this (shared, noisy) machine, measured after a warm-up "
             "call unless a column says compile/cold; every ratio compares two implementations "
             "measured side by side in this run. Goals are reported as measured, not asserted.",
             "", "## Goals of issue 13 (as measured in this run)", "",
             "Each row: the reference (numpy/scipy or the measured bound) and hapid timed side by "
             "side in the same script of this run; ratio = reference time / hapid time "
             "(benchmarks/README.md, \"Goals table contract\").", "", table(issue), "",
             "## Other goals (per section)", "", table(goals) if goals else "(none measured)", "",
             "## Contents", ""]  # fmt: skip
    for i, s in enumerate(sections, 1):
        lines.append(f"{i}. {s.title} ({s.seconds:.0f} s)")
    lines.append("")
    for i, s in enumerate(sections, 1):
        lines += [f"## {i}. {s.title}", "", s.markdown.strip(), ""]
        for f in s.figures:
            lines += [f"![{Path(f).stem}]({_rel(f, out)})", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true", help="reduced sizes: a few minutes in all")
    ap.add_argument("--out", default="out/bench", help="report folder (default out/bench)")
    ap.add_argument("--only", default="", help=f"comma-separated subset of {[k for k, _ in SUITE]}")
    ap.add_argument("--skip", default="", help="comma-separated sections to skip")
    args = ap.parse_args(argv)
    keys = [k for k, _ in SUITE]
    only = [k for k in args.only.split(",") if k] or keys
    skip = [k for k in args.skip.split(",") if k]
    for k in only + skip:
        if k not in keys:
            ap.error(f"unknown section {k!r}; choose from {keys}")
    if args.quick and not args.only:
        skip.append("uncertainty")  # emcee chains: minutes even at quick lengths
    todo = [(k, m) for k, m in SUITE if k in only and k not in skip]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    head = header("hapid benchmarks" + (" (--quick)" if args.quick else ""))
    print(head, flush=True)
    t0 = time.perf_counter()
    since = time.time() - 1.0  # goal files older than this run are not used
    sections: list[Section] = []
    failed = []
    for i, (key, mod) in enumerate(todo):
        print(f"\n======== {key} ({mod}.py) ========", flush=True)
        t = time.perf_counter()
        try:
            sec = importlib.import_module(mod).run(quick=args.quick, out=str(out))
        except Exception:  # noqa: BLE001  (report it, keep the other sections)
            tb = traceback.format_exc()
            print(tb, file=sys.stderr, flush=True)
            sec = Section(f"{key} — FAILED", "```\n" + tb[-4000:] + "\n```\n")
            failed.append(key)
        sec.seconds = time.perf_counter() - t
        sections.append(sec)
        pending = [k for k, _ in todo[i + 1 :]]
        path = write_report(out, sections, head, argv, time.perf_counter() - t0, pending, since)
    print(
        "\n## Goals of issue 13 (as measured in this run)\n\n"
        + table(issue_table(out, since, sections))
    )
    print(f"\nreport: {path} ({time.perf_counter() - t0:.0f} s)")
    figs = [f for s in sections for f in s.figures]
    missing = [f for f in figs if not os.path.exists(f)]
    if missing:
        print(f"missing figures: {missing}", file=sys.stderr)
    if failed:
        print(f"FAILED sections: {failed}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
