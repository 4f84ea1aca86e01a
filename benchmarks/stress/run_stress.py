"""Numerical stress cases (issue 7): print a table of every case and its outcome.

Usage: ``python benchmarks/stress/run_stress.py [--fast] [--out out/stress]``. Writes
``<out>/stress.md``. The cases live in ``cases.py`` (``tests/test_stress.py`` runs the fast
variants). Exit status 1 if any case is a silent failure.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.dirname(HERE)]

from _common import header  # noqa: E402
from cases import CASES  # noqa: E402

import hapid  # noqa: E402,F401  (float64 before any JAX computation)

COLUMNS = ("case", "setting", "expected", "measured", "outcome")


def markdown(rows) -> str:
    esc = lambda x: str(x).replace("|", "\\|")  # noqa: E731
    out = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        out.append("| " + " | ".join(esc(r[k]) for k in COLUMNS) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fast", action="store_true", help="small sizes (as in the test suite)")
    ap.add_argument("--out", default=os.path.join("out", "stress"))
    ap.add_argument("--only", default="", help="comma-separated substrings of case names")
    args = ap.parse_args(argv)
    rows, timing = [], []
    for case in CASES:
        if args.only and not any(s in case.__name__ for s in args.only.split(",")):
            continue
        t = time.perf_counter()
        try:
            got = case(fast=args.fast)
        except Exception as e:  # a crash is a finding too: report it as a row
            got = [dict(case=case.__name__, setting="", expected="", ok=False,
                        measured=f"{type(e).__name__}: {str(e)[:120]}", outcome="SILENT FAILURE")]  # fmt: skip
        dt = time.perf_counter() - t
        timing.append(f"{case.__name__}: {dt:.1f} s")
        rows.extend(got)
        print(f"[{dt:6.1f} s] {case.__name__}: " + ", ".join(r["outcome"] for r in got), flush=True)
    n_bad = sum(not r["ok"] for r in rows)
    text = "\n\n".join([
        header("hapid numerical stress cases" + (" (fast sizes)" if args.fast else "")),
        markdown(rows),
        f"{len(rows)} rows, {n_bad} silent failures. Time per case: " + "; ".join(timing),
    ])  # fmt: skip
    print(text)
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "stress.md"), "w") as fh:
        fh.write(text + "\n")
    print(f"wrote {os.path.join(args.out, 'stress.md')}")
    return 1 if n_bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
