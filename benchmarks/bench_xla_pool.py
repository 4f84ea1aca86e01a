"""XLA's CPU thread pool: the batched sweep that hung with one thread per core, and what a
larger pool costs elsewhere.

    PYTHONPATH=. python benchmarks/bench_xla_pool.py [--pools 2,4] [--repeats 2]
                                                      [--stall 40] [--out out/bench]

Each case runs in a fresh process with ``PJRT_NPROC`` set to the pool size (``import hapid``
sets it to ``max(4, cores + 2)`` when the user has not: hapid/_config.py). A process whose
CPU time stays flat for ``--stall`` seconds is declared **hung** and killed (its threads all
idle: two batched LAPACK kernels each waiting in ``jax::ParallelBatchMap`` for a worker the
other holds). Cases:

- ``sweep`` — the slow test's sweep: the paper scene, 4 gains × 4 noise levels × 4 fit
  corner frequencies × 4 seeds = 256 configurations, ``chunk=64`` (``hapid sweep``'s default);
- ``posterior`` — one held-out device of ``calibrate_predictive.py`` (quad4 rod compliance
  ×3): experiment, NLS fit, gp_corr Laplace posterior, 200 predictive draws (compile
  included: the persistent cache is off), to see what the larger pool costs where nothing
  hangs.

Prints a markdown table: case, pool, repeat, outcome (ok / hung), wall seconds; writes
``xla_pool.json`` to ``--out``. Linux only (reads ``/proc``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

SWEEP = """
from hapid import scene, sweep
cfg = scene.merge({"analysis": {"n_freq": 200}})
vary = {"controller.k": [0.4, 0.6, 0.85, 1.0], "protocol.noise": [1e-3, 5e-3, 2e-2, 5e-2],
        "fit.omega_c_hz": [3.0, 7.0, 12.0, 20.0], "protocol.seed": [0, 1, 2, 3]}
sweep.run_sweep(cfg, vary, chunk=64, progress=False)
"""

POSTERIOR = """
import sys
sys.path.insert(0, "benchmarks")
import calibrate_predictive as cp
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.uncertainty import model_error_from, posterior_laplace_samples, predictive_plants
dev = cp.device("quad4:compliance=3")
frf = estimate_frf(periodic_run(dev, Protocol(seed=0, force_noise=5e-3, pattern="paper")))
nls = cp.fit(frf)
post = cp.log_posterior(frf, nls, model_error_from("gp_corr"))
ps = posterior_laplace_samples(post, 200, nls, key=0)
om = cp.held_out_grid(frf.omega / cp.TWO_PI)
predictive_plants(ps, om, max_samples=200, seed=0)
"""

CASES = {"sweep": SWEEP, "posterior": POSTERIOR}


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` (``/proc/<pid>/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_case(code: str, pool: int, stall_s: float, cache: str) -> tuple[str, float]:
    """``(outcome, wall s)`` of ``code`` in a fresh process with a ``pool``-thread XLA pool."""
    env = {k: v for k, v in os.environ.items() if k not in ("PJRT_NPROC", "NPROC")}
    env |= {"PJRT_NPROC": str(pool), "HAPID_JAX_CACHE": cache, "PYTHONPATH": os.getcwd()}
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)  # fmt: skip
    last, since = -1.0, time.perf_counter()  # CPU seconds, and when they last changed
    while p.poll() is None:
        time.sleep(0.5)
        try:
            cpu = _cpu_s(p.pid)
        except (FileNotFoundError, ProcessLookupError):
            break
        if cpu != last:
            last, since = cpu, time.perf_counter()
        if time.perf_counter() - since >= stall_s:
            p.kill()
            p.wait()
            return "hung", time.perf_counter() - t0
    wall = time.perf_counter() - t0
    if p.wait() != 0:
        return f"error: {p.stderr.read().strip().splitlines()[-1]}", wall
    return "ok", wall


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pools", default="2,4", help="pool sizes (PJRT_NPROC), default 2,4")
    ap.add_argument("--cases", default="sweep,posterior")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--stall", type=float, default=40.0, help="seconds of flat CPU = hung")
    ap.add_argument("--out", default="out/bench")
    a = ap.parse_args(argv)
    if not sys.platform.startswith("linux"):
        sys.exit("bench_xla_pool.py reads /proc: Linux only")
    pools = [int(x) for x in a.pools.split(",")]
    rows = []
    print(f"cores: {os.cpu_count()}\n")
    print("| case | pool (PJRT_NPROC) | repeat | outcome | wall s |\n|---|---|---|---|---|")
    for case in a.cases.split(","):
        for r in range(a.repeats):
            for pool in pools:  # interleaved: the machine's drift hits both pools alike
                cache = "" if case == "posterior" else os.path.join("out", "bench", "jax_pool")
                outcome, wall = run_case(CASES[case], pool, a.stall, cache)
                rows.append({"case": case, "pool": pool, "repeat": r, "outcome": outcome,
                             "wall_s": wall})  # fmt: skip
                print(f"| {case} | {pool} | {r} | {outcome} | {wall:.1f} |", flush=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "xla_pool.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
