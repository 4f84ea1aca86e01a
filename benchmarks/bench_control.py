"""Benchmark: loop analysis (``hapid.control.analyze_loop``) for one model and vmapped batches.

Run: ``.venv/bin/python benchmarks/bench_control.py [--batch 1000] [--freqs 1000] [--n 5]``.
Prints machine and versions, then a table of compile and run times (best of 3 runs after
compilation). Plants are random n-rod second-order models (``hapid.control._examples``)
under the inverse-model controller designed on a perturbed model, so every loop is a
realistic one (loci, crossings, Nyquist count all exercised).

Recorded (x86_64, 2 shared cores, python 3.11.7, jax 0.10.2, CPU; n = 5, N = 1000):

    case               compile [s]   run [s]  per loop [ms]
    1 model                   0.30     0.049         49.4
    vmap batch 100            1.74     3.376         33.8
    vmap batch 1000           3.12    32.255         32.3

About half of the run time is the five batched SVDs (σ of I+L, S, T, S−T, L), a fifth
the eigenvalues, the rest loci tracking (120-permutation matching for n = 5; the
``loci_method="greedy"`` option is ~5× cheaper for that part).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import hapid
from hapid.control import Compensator, analyze_loop, inverse_model_response
from hapid.control._examples import example_model


def _timeit(f, *args, repeat=3):
    t0 = time.perf_counter()
    jax.block_until_ready(f(*args))
    first = time.perf_counter() - t0
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        best = min(best, time.perf_counter() - t0)
    return first - best, best


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=1000)
    ap.add_argument("--freqs", type=int, default=1000)
    ap.add_argument("--n", type=int, default=5)
    args = ap.parse_args()
    B, N, n = args.batch, args.freqs, args.n

    print(f"machine: {platform.machine()} {platform.processor() or ''} cpus={os.cpu_count()}")
    print(f"python {platform.python_version()}, jax {jax.__version__}, hapid {hapid.__version__}")
    print(f"devices: {jax.devices()}")

    w = jnp.logspace(-1, 3.5, N)
    g = Compensator.paper()
    models = [example_model(n, seed=s) for s in range(8)]
    Pj = jnp.stack([m.P(1j * w) for m in models])
    Gj = jnp.stack([inverse_model_response(example_model(n, seed=s + 100), g, w) for s in range(8)])
    idx = np.arange(B) % 8
    PB, GB = Pj[idx], Gj[idx]

    single = jax.jit(lambda P, G: analyze_loop(P, G, w))
    batched = jax.jit(jax.vmap(lambda P, G: analyze_loop(P, G, w)))
    rows = []
    c, r = _timeit(single, Pj[0], Gj[0])
    rows.append(("1 model", 1, c, r))
    for b in sorted({min(100, B), B}):
        c, r = _timeit(batched, PB[:b], GB[:b])
        rows.append((f"vmap batch {b}", b, c, r))
    print(f"\nanalyze_loop, n = {n}, N = {N} frequencies")
    print(f"{'case':<18}{'compile [s]':>12}{'run [s]':>10}{'per loop [ms]':>15}")
    for name, b, c, r in rows:
        print(f"{name:<18}{c:>12.2f}{r:>10.3f}{1e3 * r / b:>15.3f}")
    rep = single(Pj[0], Gj[0])
    print(
        "\nexample summary:",
        {k: round(v, 3) if isinstance(v, float) else v for k, v in rep.summary().items()},
    )


if __name__ == "__main__":
    main()
