"""Benchmark: the LAPACK reference loop analysis (``analyze_loop`` of ``tests/oracle_loop.py``,
the tests' independent check of :func:`hapid.control.loop_metrics`) for one model and vmapped
batches; the production path's timings are ``bench_fast.py`` and ``bench_n.py``.

Run: ``.venv/bin/python benchmarks/bench_control.py [--quick] [--out out/bench]`` (batch 50
with --quick, 500 otherwise).
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

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Section, fs, measure, standalone, table  # noqa: E402

import hapid  # noqa: E402,F401
from hapid.control import Compensator, inverse_model_response  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from oracle_loop import analyze_loop  # noqa: E402
from oracles import example_model  # noqa: E402


def run(
    quick: bool = False,
    out: str = "out/bench",
    batch: int | None = None,
    freqs: int = 1000,
    n: int = 5,
) -> Section:
    sec = Section("Loop analysis: one model and vmapped batches")
    B = batch if batch is not None else (50 if quick else 500)
    N = freqs
    w = jnp.logspace(-1, 3.5, N)
    g = Compensator.paper()
    models = [example_model(n, seed=s) for s in range(8)]
    Pj = jnp.stack([m.P(1j * w) for m in models])
    Gj = jnp.stack([inverse_model_response(example_model(n, seed=s + 100), g, w) for s in range(8)])
    idx = np.arange(B) % 8
    PB, GB = Pj[idx], Gj[idx]

    single = jax.jit(lambda P, G: analyze_loop(P, G, w))
    batched = jax.jit(jax.vmap(lambda P, G: analyze_loop(P, G, w)))
    greedy = jax.jit(jax.vmap(lambda P, G: analyze_loop(P, G, w, loci_method="greedy")))
    rows = []

    def add(name, b, fn, *args, repeat):
        _, first, r = measure(lambda: fn(*args), repeat=repeat)
        rows.append({"case": name, "loops": b, "compile ≈": fs(max(first - r, 0)), "run": fs(r),
                     "per loop": fs(r / b), "loops/s": f"{b / r:,.1f}"})  # fmt: skip

    add("1 model (jit)", 1, single, Pj[0], Gj[0], repeat=5)
    for b in sorted({min(100, B), B}):
        add(f"vmap batch {b}", b, batched, PB[:b], GB[:b], repeat=1 if b >= 500 else 3)
    if not quick:
        b = min(100, B)
        add(f"vmap batch {b}, loci_method='greedy'", b, greedy, PB[:b], GB[:b], repeat=3)
    sec.add(f"analyze_loop (LAPACK reference, tests/oracle_loop.py), n = {n}, N = {N} frequencies, random second-order plants under an "
            "inverse-model controller designed on a perturbed model (`hapid.control._examples`).\n\n"
            + table(rows))  # fmt: skip
    rep = single(Pj[0], Gj[0])
    summ = {k: round(v, 3) if isinstance(v, float) else v for k, v in rep.numbers().items()}
    sec.add(f"example summary: {summ}")
    return sec


def main(argv=None):
    return standalone(run, __doc__, argv)


if __name__ == "__main__":
    main()
