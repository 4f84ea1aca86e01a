"""Scaling in n: compile and warm time of the eigenvalue kernels and the loop analysis, n = 3..7.

    HAPID_JAX_CACHE= PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_n.py [--ns 3,4,5,6,7] [--N 1000]

(``HAPID_JAX_CACHE=`` empty disables the persistent compilation cache, so the compile
columns are compiles, not cache loads; with a cache they measure the load.)

For each n, N = 1000 frequencies:

- ``K.eigvals`` (``hapid.control._kernels``: Hessenberg + shifted QR as XLA ops for
  ``n ≤ MAX_EIG_N``, LAPACK above) on random complex matrices: compile (``jit(f).lower(x)
  .compile()``: wall and process CPU time — the CPU time is what the compile costs when the
  machine is shared), warm (median of 15 calls), and the largest error against numpy's
  ``np.linalg.eigvals`` after the optimal matching, relative to ``‖A‖_F``.
- ``K.pair_optimal`` on two random eigenvalue sets: compile, warm, and whether every
  permutation equals the brute-force optimal one over all n! permutations (costs compared:
  the DP's cost must equal the minimum).
- ``hapid.control.loop_metrics`` (default spec) on a loop built like ``bench_fast.py``
  builds cu5's, with the device's rigid model for the controller: ``G = g(jω) Z_T Z_H⁻¹``
  (``inverse_model_response(dev.rigid_model(), Compensator.paper(), ω)``), ``P = dev.sampled_P(ω)``
  on ``posterior_omega(N)``; devices tripod3 (n = 3), quad4 (4), cu5 (5), hexapod6 (6) with
  their default keywords; n = 7 has no preset, so it is the block-diagonal loop
  tripod3 ⊕ quad4 (7 × 7, its loci are the union of the two). Compile, warm, and the
  largest gap to the LAPACK path (``MetricsSpec(kernels="lapack")``) over GM (dB), PM (deg)
  and the bandwidth (Hz), plus whether the verdicts agree. The loop's eigenvalues from
  ``K.eigvals`` against numpy's are in the ``loop eig err`` column.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import header, table  # noqa: E402

import hapid  # noqa: E402,F401  (float64)
from hapid.control import _kernels as K  # noqa: E402


def _compile(fn, *args):
    """(compiled, wall s, process CPU s) of ``jit(fn)`` on ``args``."""
    t, c = time.perf_counter(), time.process_time()
    comp = jax.jit(fn).lower(*args).compile()
    return comp, time.perf_counter() - t, time.process_time() - c


def _warm(fn, *args, repeat=15):
    jax.block_until_ready(fn(*args))
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def _match_err(e, r):
    """Largest |e − r| per row after the optimal matching of ``e (B, n)`` to ``r (B, n)``
    (the tests' matching: the permutation minimizing the largest gap; n ≤ 7)."""
    n = e.shape[1]
    perms = np.array(list(itertools.permutations(range(n))))
    out = np.empty(len(e))
    for s in range(0, len(e), 100):
        d = np.max(np.abs(e[s : s + 100, perms] - r[s : s + 100, None, :]), axis=2)
        out[s : s + 100] = d.min(axis=1)
    return out


def _brute_pairing_cost(a, b):
    """Minimal Σ|a_i − b_σ(i)|² over every permutation, per column of ``a, b (n, B)``."""
    n = a.shape[0]
    perms = np.array(list(itertools.permutations(range(n))))
    return np.min(np.sum(np.abs(a.T[:, None, :] - b.T[:, perms]) ** 2, axis=2), axis=1)


def _device_loop(n, omega):
    """(P, G, p_ol, label) of the preset loop of size ``n`` (module docstring)."""
    from hapid.control import Compensator, controller_unstable_poles, inverse_model_response
    from hapid.device import cu5, hexapod6, quad4, tripod3

    g = Compensator.paper()

    def one(dev):
        m = dev.rigid_model()
        P = np.asarray(dev.sampled_P(omega))
        G = np.asarray(inverse_model_response(m, g, omega))
        return P, G, int(controller_unstable_poles(m, g))

    makers = {3: (tripod3,), 4: (quad4,), 5: (cu5,), 6: (hexapod6,), 7: (tripod3, quad4)}
    if n not in makers:
        return None
    parts = [one(mk()) for mk in makers[n]]
    N = len(omega)
    P = np.zeros((N, n, n), complex)
    G = np.zeros((N, n, n), complex)
    i = 0
    for Pk, Gk, _ in parts:
        k = Pk.shape[-1]
        P[:, i : i + k, i : i + k], G[:, i : i + k, i : i + k] = Pk, Gk
        i += k
    label = " ⊕ ".join(mk.__name__ for mk in makers[n])
    return P, G, sum(p for *_, p in parts), label


def row(n: int, N: int = 1000, loop: bool = True) -> dict:
    rng = np.random.default_rng(n)
    A = rng.standard_normal((N, n, n)) + 1j * rng.standard_normal((N, n, n))
    Ae = K.to_entries(jnp.asarray(A))
    eig, ec, ecp = _compile(K.eigvals, Ae)
    e = np.asarray(eig(Ae)).T
    err = _match_err(e, np.linalg.eigvals(A)) / np.linalg.norm(A, axis=(1, 2))
    r = {"n": n, "eig compile s (cpu)": f"{ec:.1f} ({ecp:.1f})",
         "eig warm ms": f"{_warm(eig, Ae) * 1e3:.2f}", "eig err/‖A‖": f"{err.max():.1e}"}  # fmt: skip

    a = rng.standard_normal((n, N)) + 1j * rng.standard_normal((n, N))
    b = a + 0.7 * (rng.standard_normal((n, N)) + 1j * rng.standard_normal((n, N)))
    aj, bj = jnp.asarray(a), jnp.asarray(b)
    pair, pc, pcp = _compile(K.pair_optimal, aj, bj)
    got = np.asarray(pair(aj, bj))
    cost = np.sum(np.abs(a - got) ** 2, axis=0)
    best = _brute_pairing_cost(a, b)
    ok = np.all(np.sort(got, axis=0) == np.sort(b, axis=0)) and np.allclose(cost, best, rtol=1e-12)
    r |= {"pair compile s (cpu)": f"{pc:.1f} ({pcp:.1f})",
          "pair warm ms": f"{_warm(pair, aj, bj) * 1e3:.2f}", "pair optimal": "yes" if ok else "NO"}  # fmt: skip

    if loop:
        r |= _loop_cols(n, N)
    return r


def _loop_cols(n, N):
    from hapid.control import MetricsSpec, loop_metrics
    from hapid.uncertainty import posterior_omega

    omega = np.asarray(posterior_omega(N))
    dl = _device_loop(n, omega)
    if dl is None:
        return {"loop": "(no preset)"}
    P, G, p_ol, label = dl
    w = jnp.asarray(omega)
    Pj, Gj = jnp.asarray(P), jnp.asarray(G)
    f = jax.jit(lambda P, G: loop_metrics(P, G, w, p_ol=p_ol))
    lm, lc, lcp = _compile(f, Pj, Gj)
    q = lm(Pj, Gj)
    lap = jax.jit(lambda P, G: loop_metrics(P, G, w, p_ol=p_ol, spec=MetricsSpec(kernels="lapack")))
    ql = lap(Pj, Gj)
    gaps = []
    for k in ("gm_db", "pm_deg", "iso_bandwidth_hz"):
        x, y = float(getattr(q, k)), float(getattr(ql, k))
        gaps.append(0.0 if (x == y or (np.isnan(x) and np.isnan(y))) else abs(x - y))
    same = bool(q.stable == ql.stable) and int(q.n_encirclements) == int(ql.n_encirclements)
    L = P @ G
    Le = K.to_entries(jnp.asarray(L))
    e = np.asarray(jax.jit(K.eigvals)(Le)).T
    lerr = _match_err(e, np.linalg.eigvals(L)) / np.linalg.norm(L, axis=(1, 2))
    return {"loop": label, "loop compile s (cpu)": f"{lc:.1f} ({lcp:.1f})",
            "loop warm ms": f"{_warm(lm, Pj, Gj, repeat=7) * 1e3:.1f}",
            "GM/PM/bw gap to lapack": "/".join(f"{g:.0e}" for g in gaps),
            "verdict = lapack": "yes" if same else "NO", "loop eig err/‖L‖": f"{lerr.max():.1e}"}  # fmt: skip


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ns", default="3,4,5,6,7", help="comma-separated sizes n")
    p.add_argument("--N", type=int, default=1000, help="frequencies (batch)")
    p.add_argument("--no-loop", action="store_true", help="kernels only")
    args = p.parse_args(argv)
    print(header(__doc__.strip().splitlines()[0]), flush=True)
    print(f"MAX_EIG_N = {K.MAX_EIG_N} (LAPACK eigvals above), N = {args.N}\n", flush=True)
    rows = []
    for n in (int(x) for x in args.ns.split(",")):
        rows.append(row(n, args.N, loop=not args.no_loop))
        print(table(rows[-1:]), flush=True)
    print("\n" + table(rows))
    return rows


if __name__ == "__main__":
    main()
