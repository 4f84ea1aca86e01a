"""Issue 13 (fast): loop analysis and robust check, numpy vs the LAPACK reference vs loop_metrics.

Run: ``.venv/bin/python benchmarks/bench_fast.py [--quick]`` (100 posterior draws with
--quick, 1000 otherwise). Everything is measured side by side in this run, on cu5 (the paper
device): the paper protocol's FRF, the NLS model, the inverse-model controller with the
paper's g, Laplace posterior draws of the NLS fit.

1. One loop, n = 5, N = 3000 frequencies (posterior grid, 0.005 Hz–5 kHz): numpy (``det``,
   ``inv``, ``eigvals``, ``svd`` on the stack — the ingredients of the verdict, σ̄(T − I)
   and the loci margins), :func:`hapid.control.analyze_loop` (LAPACK reference, grid
   values) and :func:`hapid.control.loop_metrics` (XLA kernels, screened, refined).
2. Robust check, S draws × 1000 frequencies: :func:`hapid.uncertainty.robust_check` (now
   loop_metrics, vmapped over padded chunks) against the per-plant reference
   (``analyze_loop`` on every draw, jitted once): time and verdict agreement.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Section, fg, fs, measure, standalone, table  # noqa: E402

import hapid  # noqa: E402,F401


def _setup():
    from hapid.device import cu5
    from hapid.experiment import Protocol, estimate_frf, periodic_run
    from hapid.fit import fit_nls

    frf = estimate_frf(periodic_run(cu5(), Protocol(), noise_seed=0))
    return fit_nls(frf)


def _numpy_loop(P, G):
    L = P @ G
    n = L.shape[-1]
    IL = L + np.eye(n)
    det = np.linalg.det(IL)
    S = np.linalg.inv(IL)
    lam = np.linalg.eigvals(L)
    sv_S = np.linalg.svd(S, compute_uv=False)
    sv_T = np.linalg.svd(np.eye(n) - S, compute_uv=False)
    return det, lam, sv_S, sv_T


def loop_row(sec: Section, nls, N: int = 3000):
    from hapid.control import (
        Compensator,
        MetricsSpec,
        analyze_loop,
        controller_unstable_poles,
        inverse_model_response,
        loop_metrics,
    )
    from hapid.uncertainty import laplace_samples, posterior_omega

    g = Compensator.paper()
    w = jnp.asarray(posterior_omega(N))
    draw = laplace_samples(nls, 1, key=5).models(np.arange(1))
    m = jax.tree.map(lambda a: a[0], draw)
    P = m.P(1j * w)
    G = inverse_model_response(nls.model, g, w)
    p_ol = int(controller_unstable_poles(nls.model, g))
    Pn, Gn = np.asarray(P), np.asarray(G)
    ref = jax.jit(lambda P, G: analyze_loop(P, G, w, p_ol))
    spec = MetricsSpec(disk=True)
    _, _, t_np = measure(lambda: _numpy_loop(Pn, Gn), repeat=5)
    r, c_ref, t_ref = measure(lambda: ref(P, G), repeat=5)
    q, c_new, t_new = measure(lambda: loop_metrics(P, G, w, p_ol=p_ol, spec=spec), repeat=5)
    rows = [
        {"implementation": "numpy det+inv+eigvals+2 svd", "run": fs(t_np), "vs numpy": "1×",
         "first call": "", "exact fallback": ""},
        {"implementation": "analyze_loop (LAPACK, grid)", "run": fs(t_ref), "vs numpy": f"{t_np / t_ref:.2f}×",
         "first call": fs(c_ref), "exact fallback": ""},
        {"implementation": "loop_metrics (XLA kernels, refined)", "run": fs(t_new),
         "vs numpy": f"{t_np / t_new:.2f}×", "first call": fs(c_new),
         "exact fallback": bool(q.exact_fallback)},
    ]  # fmt: skip
    sec.add(
        f"### 1. One loop: cu5 posterior draw under the NLS design, n = 5, N = {N}\n\n"
        + table(rows)
    )
    a, b = r.summary(), q.summary()
    agree = [{"field": k, "analyze_loop (grid)": fg(a[k], 7), "loop_metrics (refined)": fg(b[k], 7)}
             for k in ("stable", "iso_bandwidth_hz", "gm_db", "pm_deg", "t_peak_db", "disk_margin")]  # fmt: skip
    sec.add(table(agree))
    sec.rows["loop_vs_numpy"] = t_np / t_new
    sec.goal("loop analysis ≥ 30× numpy (warm)",
             f"{t_np / t_new:.2f}× (numpy {fs(t_np)}, loop_metrics {fs(t_new)}, analyze_loop {fs(t_ref)})",
             t_np / t_new >= 30)  # fmt: skip


def robust_row(sec: Section, nls, S: int):
    from hapid.control import (
        Compensator,
        analyze_loop,
        controller_unstable_poles,
        inverse_model_response,
    )
    from hapid.uncertainty import laplace_samples, posterior_omega, robust_check

    g = Compensator.paper()
    omega = posterior_omega(1000)
    samples = laplace_samples(nls, S, key=0)
    chunk = min(S, 250)
    t = time.perf_counter()
    robust_check(samples, (nls.model, g), omega, max_samples=chunk, chunk=chunk, backend="metrics")
    first = time.perf_counter() - t
    t = time.perf_counter()
    rep = robust_check(
        samples, (nls.model, g), omega, max_samples=S, chunk=chunk, backend="metrics"
    )
    dt = time.perf_counter() - t
    # the per-plant reference: analyze_loop on every draw (one jitted program, a python loop)
    w = jnp.asarray(omega)
    G = inverse_model_response(nls.model, g, w)
    p_ol = float(controller_unstable_poles(nls.model, g))
    ref = jax.jit(lambda P: analyze_loop(P, G, w, p_ol))
    models = samples.models(np.arange(S))
    Ps = jax.jit(jax.vmap(lambda mm: mm.P(1j * w)))(models)
    jax.block_until_ready(ref(Ps[0]))
    t = time.perf_counter()
    reps = [ref(Ps[i]) for i in range(S)]
    st_ref = np.array([bool(x.stable) for x in reps])
    t_ref = time.perf_counter() - t
    gm_ref = np.array([float(x.gm_db) for x in reps])
    same = int(np.sum(st_ref == rep.stable))
    both = st_ref & rep.stable
    dgm = float(np.max(np.abs(gm_ref[both] - rep.gm_db[both]))) if both.any() else float("nan")
    sec.add(f"### 2. Robust check: {S} Laplace draws of cu5 × 1000 frequencies (posterior grid)\n\n"
            + table([{"implementation": "robust_check(backend='metrics'): loop_metrics, vmapped chunks", "time": fs(dt),
                      "per draw": fs(dt / S), f"first call ({chunk} draws, incl. compile)": fs(first),
                      "P(stable)": fg(rep.p_stable)},
                     {"implementation": "analyze_loop per draw (reference)", "time": fs(t_ref),
                      "per draw": fs(t_ref / S), "P(stable)": fg(float(np.mean(st_ref)))}])
            + f"\n\nverdicts identical: {same}/{S}; max |GM(refined) − GM(grid)| over stable draws: "
            f"{dgm:.3g} dB")  # fmt: skip
    per_1000 = dt / S * 1000
    sec.rows["robust_1000_s"] = per_1000
    sec.goal("robust check 1000 draws × 1000 freq ≤ 2 s warm, same verdicts",
             f"{fs(per_1000)} per 1000 draws (measured {S}: {fs(dt)}; reference {fs(t_ref / S * 1000)}); "
             f"verdicts {same}/{S}", per_1000 <= 2 and same == S)  # fmt: skip


def run(quick: bool = False, out: str = "out/bench") -> Section:
    sec = Section(
        "Issue 13: loop analysis and robust check (numpy / LAPACK reference / XLA kernels)"
    )
    nls = _setup()
    loop_row(sec, nls)
    robust_row(sec, nls, 100 if quick else 1000)
    return sec


def main(argv=None):
    return standalone(run, __doc__, argv)


if __name__ == "__main__":
    main()
