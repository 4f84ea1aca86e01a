"""The user's route through the CLI, before and after: fit, posterior, robust, analyze, tune.

Run: ``.venv/bin/python benchmarks/bench_route.py [--before COMMIT] [--runs 3] [--quick]
[--only fit,posterior,robust,analyze,tune] [--profile] [--numpy] [--data DIR] [--out DIR]``
from the repository root.

``COMMIT`` (default: the parent of the first commit of this work, :data:`BEFORE`) is
extracted with ``git archive`` into a temporary folder; "after" is this checkout. Each
command runs as a whole process (``python -m hapid …``, start-up included) with its tree on
``PYTHONPATH`` and its own JAX persistent-cache folder (``HAPID_JAX_CACHE``):

* **cold**: one run with an empty cache folder (everything compiled);
* **warm**: ``--runs`` further runs on the filled folder (median, min–max), before and after
  alternating (A B A B …) so that both see the same machine load; the ratio is taken per pair.

Wall time and CPU time (user + system of the child, from ``os.wait4``) are both reported: on
a shared machine the CPU time is the steadier figure. The route's data (cu5, the paper
protocol: run, FRF, NLS model, 1000 Laplace draws) are made once, by "after", and both trees
read the same files. With ``--profile``, each command of "after" is also run in one process
twice (:mod:`_route_profile`): import, first call and second call, I/O — the profile table
of benchmarks/README.md. With ``--numpy``, the parameter-draw robust check against a plain numpy
loop over the same 1000 plants (:func:`hapid.uncertainty.robust_check` vs numpy), in each tree.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import header, table  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BEFORE = "e1aa3df"
"""The commit the route was first timed on (issue 28's figures)."""
PY = sys.executable


def _routes(d: Path, quick: bool) -> dict[str, list[str]]:
    draws = "100" if quick else "1000"
    return {
        "fit nls": ["fit", f"{d}/frf.npz", "--method", "nls", "--out", f"{d}/o_nls.npz"],
        "posterior laplace": [
            "posterior",
            f"{d}/frf.npz",
            "--method",
            "laplace",
            "--samples",
            draws,
            "--out",
            f"{d}/o_samples.npz",
        ],  # fmt: skip
        "robust (1 model)": [
            "robust",
            "--samples",
            f"{d}/samples.npz",
            "--model",
            f"{d}/nls.npz",
            "--max-samples",
            draws,
            "--out",
            f"{d}/o_robust.json",
        ],  # fmt: skip
        "analyze (1 loop)": [
            "analyze",
            "--model",
            f"{d}/nls.npz",
            "--device",
            "cu5",
            "--out",
            f"{d}/o_report.json",
        ],  # fmt: skip
        "tune (default route)": [
            "tune",
            "--model",
            f"{d}/nls.npz",
            "--samples",
            f"{d}/samples.npz",
            "--fs",
            "1000",
            "--out",
            f"{d}/o_design.npz",
        ],  # fmt: skip
    }


def run_cmd(tree: Path, args: list[str], cache: Path, timeout: float = 3600.0) -> dict:
    """One whole-process run of ``python -m hapid args`` on ``tree``: wall seconds, exit
    code, the last line of output."""
    env = dict(os.environ, PYTHONPATH=str(tree), HAPID_JAX_CACHE=str(cache))
    t = time.perf_counter()
    p = subprocess.Popen([PY, "-m", "hapid", *args], cwd=tree, env=env, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT)  # fmt: skip
    out, _ = p.communicate(timeout=timeout)
    return {
        "wall": time.perf_counter() - t,
        "rc": p.returncode,
        "tail": out.strip().splitlines()[-1:],
    }


def _timed(tree: Path, args, cache: Path) -> dict:
    """:func:`run_cmd` with the child's CPU time from ``resource`` (children's usage delta)."""
    import resource

    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    res = run_cmd(tree, args, cache)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    res["cpu"] = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return res


def make_data(d: Path, quick: bool) -> None:
    """The route's input files (cu5, paper protocol), made by this checkout."""
    cache = d / "cache_data"
    steps = [["simulate", "--device", "cu5", "--out", f"{d}/run.npz"],
             ["frf", f"{d}/run.npz", "--out", f"{d}/frf.npz"],
             ["fit", f"{d}/frf.npz", "--method", "nls", "--out", f"{d}/nls.npz"],
             ["posterior", f"{d}/frf.npz", "--method", "laplace", "--samples",
              "100" if quick else "1000", "--out", f"{d}/samples.npz"]]  # fmt: skip
    for s in steps:
        r = run_cmd(ROOT, s, cache)
        if r["rc"] != 0:
            raise SystemExit(f"data step failed: hapid {' '.join(s)}: {r['tail']}")


def _med(xs):
    return statistics.median(xs) if xs else float("nan")


def _span(xs):
    return f"{_med(xs):.1f} ({min(xs):.1f}–{max(xs):.1f})" if xs else "-"


def route(before: Path, d: Path, runs: int, quick: bool, only: list[str]) -> list[dict]:
    """One row per command of ``only`` (name prefixes, in that order): cold and warm."""
    rows = []
    routes = _routes(d, quick)
    for key in only:
        name = next(k for k in routes if k.startswith(key))
        args = routes[name]
        res = {}
        for label, tree in (("before", before), ("after", ROOT)):
            cold_cache = d / f"cold_{label}_{len(rows)}"
            res[label] = {"cold": _timed(tree, args, cold_cache), "cache": cold_cache, "warm": []}
        for _ in range(runs):  # A B A B …: the pairs share the machine's load
            for label, tree in (("before", before), ("after", ROOT)):
                res[label]["warm"].append(_timed(tree, args, res[label]["cache"]))
        wb = [r["wall"] for r in res["before"]["warm"]]
        wa = [r["wall"] for r in res["after"]["warm"]]
        cb = [r["cpu"] for r in res["before"]["warm"]]
        ca = [r["cpu"] for r in res["after"]["warm"]]
        rc = {r["rc"] for lab in res.values() for r in [lab["cold"], *lab["warm"]]}
        row = {"command": name,
               "cold before (s)": f"{res['before']['cold']['wall']:.1f}",
               "cold after (s)": f"{res['after']['cold']['wall']:.1f}",
               "warm before: wall s, median (min–max)": _span(wb),
               "warm after": _span(wa),
               "after/before wall (median of pairs)": f"{_med([a / b for a, b in zip(wa, wb, strict=True)]):.2f}",
               "warm CPU before (s)": f"{_med(cb):.1f}", "warm CPU after (s)": f"{_med(ca):.1f}",
               "exit codes": ",".join(map(str, sorted(rc)))}  # fmt: skip
        rows.append(row)
        print(table([row]), flush=True)
    return rows


def robust_vs_numpy(before: Path, S: int) -> list[dict]:
    """The parameter-draw robust check against a numpy loop, in each tree (one process each)."""
    rows = []
    script = Path(__file__).resolve().parent / "_route_numpy.py"
    for label, tree in (("before", before), ("after", ROOT)):
        env = dict(os.environ, PYTHONPATH=str(tree))
        p = subprocess.run([PY, str(script), str(S)], cwd=tree, env=env, text=True,
                           capture_output=True, timeout=3600)  # fmt: skip
        try:
            r = json.loads(p.stdout.strip().splitlines()[-1])
        except (IndexError, json.JSONDecodeError):
            rows.append({"tree": label, "error": (p.stderr or p.stdout).strip()[-300:]})
            continue
        rows.append({"tree": label, "draws": S, "robust_check warm (s)": f"{r['t_hapid']:.2f}",
                     "numpy loop (s)": f"{r['t_numpy']:.2f}", "× numpy": f"{r['t_numpy'] / r['t_hapid']:.2f}",
                     "verdicts = LAPACK reference": f"{r['same']}/{S}"})  # fmt: skip
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default=BEFORE, help="git commit of 'before'")
    ap.add_argument("--runs", type=int, default=3, help="warm runs per tree (default 3)")
    ap.add_argument("--quick", action="store_true", help="100 draws instead of 1000")
    ap.add_argument("--only", default="fit,posterior,robust,analyze,tune",
                    help="commands to time, in this order (comma list of fit, posterior, robust, "
                    "analyze, tune; default all)")  # fmt: skip
    ap.add_argument("--profile", action="store_true", help="also each command's profile (after)")
    ap.add_argument("--numpy", action="store_true", help="also the parameter-draw check vs numpy")
    ap.add_argument("--data", help="a folder with the route's inputs (run, frf, nls, samples .npz) "
                    "from an earlier run: reused instead of made")  # fmt: skip
    ap.add_argument("--out", default="out/bench")
    a = ap.parse_args(argv)
    only = [k.strip() for k in a.only.split(",") if k.strip()]
    print(header("bench_route: the CLI route, before and after"), flush=True)
    tmp = Path(tempfile.mkdtemp(prefix="hapid_route_"))
    try:
        before = tmp / "before"
        before.mkdir()
        arch = subprocess.run(
            ["git", "archive", a.before], cwd=ROOT, capture_output=True, check=True
        )
        subprocess.run(["tar", "-x", "-C", str(before)], input=arch.stdout, check=True)
        print(f"before: {a.before} (git archive → {before}); after: {ROOT}", flush=True)
        if a.data:
            for f in ("run.npz", "frf.npz", "nls.npz", "samples.npz"):
                if (Path(a.data) / f).exists():  # a command whose input is absent fails alone
                    shutil.copy(Path(a.data) / f, tmp / f)
        else:
            make_data(tmp, a.quick)
        md = ["## Route (whole processes, `python -m hapid …`)", "",
              f"command: `python benchmarks/bench_route.py --before {a.before} --runs {a.runs}"
              + (" --quick" if a.quick else "") + f" --only {a.only}`", ""]  # fmt: skip
        md.append(table(route(before, tmp, a.runs, a.quick, only)))
        if a.profile:
            from _route_profile import profile_rows

            routes = _routes(tmp, a.quick)
            sel = {k: v for k, v in routes.items() if any(k.startswith(o) for o in only)}
            md += ["", "## Profile of 'after' (one process, the command run twice)", ""]
            md.append(table(profile_rows(ROOT, sel, tmp / "cache_profile")))
        if a.numpy:
            S = 100 if a.quick else 1000
            md += ["", f"## Parameter-draw robust check vs a numpy loop ({S} draws × 1000 "
                   "frequencies)", ""]  # fmt: skip
            md.append(table(robust_vs_numpy(before, S)))
        text = "\n".join(md)
        print("\n" + text)
        Path(a.out).mkdir(parents=True, exist_ok=True)
        (Path(a.out) / "bench_route.md").write_text(text + "\n")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
