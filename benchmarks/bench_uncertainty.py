"""Benchmark and deliverable numbers of hapid.uncertainty (not part of the test run).

Run: ``.venv/bin/python benchmarks/bench_uncertainty.py [--quick] [--full-chain]``.
``run_all.py`` runs it with the quick chain lengths (3000 emcee steps; the full-length chains
to ≥ 50 τ take many minutes: ``--full-chain``), and skips it under ``run_all.py --quick``.

1. log-probability evaluations/s: jitted + vmapped JAX vs the plain-numpy reference, cu5.
2. emcee move comparison (DE vs stretch vs DE + 10 % γ = 1) on a small strictly
   second-order case: ESS per second at a fixed number of steps.
3. A whole emcee run on cu5 data (paper protocol, NLS fit first) to ≥ 50 τ: τ, ESS, ESS/s.
4. Robust check over 1000 posterior samples × 1000 frequencies, timed.
5. WLS- vs NLS-designed controller (paper g): P(stable) and margin quantiles over the
   posterior, and on the device (nominal, 6 poses ±4 cm, 10 virtual subjects).
6. Pose study (7 poses): nominal vs re-identified controller.
"""

from __future__ import annotations

import contextlib
import io
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from _common import Section, standalone, table, timeit  # noqa: E402
from oracles import log_prob_numpy  # noqa: E402

import hapid  # noqa: E402,F401
from hapid.control import Compensator  # noqa: E402
from hapid.device import cu5  # noqa: E402
from hapid.experiment import Protocol, estimate_frf, periodic_run  # noqa: E402
from hapid.fit import fit_nls, wls  # noqa: E402
from hapid.tune._recipe_plants import TRAIN_OFFSETS  # noqa: E402
from hapid.uncertainty import (  # noqa: E402
    ShortChainWarning,
    batched_log_prob,
    device_plants,
    initial_point,
    laplace_posterior,
    make_log_posterior,
    pose_study,
    robust_check,
    robust_omega,
    sample_posterior,
)

QUICK = "--full-chain" not in sys.argv


def fmt(x, p=3):
    return f"{x:.{p}g}" if isinstance(x, float) else str(x)


def _body():
    print(f"chains: {'quick (3000 steps)' if QUICK else 'full (to >= 50 tau)'}")
    dev = cu5()
    t = time.perf_counter()
    frf = estimate_frf(periodic_run(dev, Protocol(), noise_seed=0))
    nls = fit_nls(frf, weight="relative").raise_if_failed()
    print(f"\ncu5 FRF + NLS (relative, 40 Hz): {time.perf_counter() - t:.1f} s; {nls.report()}")
    post = make_log_posterior(frf, nls.scale)
    x0 = initial_point(post, nls)
    t = time.perf_counter()
    lp = laplace_posterior(post, x0)
    mean, cov = lp.mean, lp.cov
    print(f"Laplace of the posterior: {time.perf_counter() - t:.1f} s, {lp.info()}; "
          f"tau_H, tau_M at MAP = {np.exp(mean[-2:]).round(3)}")  # fmt: skip

    # 1. log-prob throughput ----------------------------------------------------------------
    W = 2 * post.dim + 2
    X = np.random.default_rng(0).multivariate_normal(mean, cov, W)
    f = batched_log_prob(post)
    f(X)
    tj = timeit(lambda: f(X), repeat=7, number=20)
    tn = timeit(lambda: log_prob_numpy(post, X[:20]), repeat=3) * W / 20
    rows = [
        {"implementation": "jax jit+vmap", "walkers": W, "s/call": fmt(tj), "evals/s": fmt(W / tj)},
        {
            "implementation": "numpy reference",
            "walkers": W,
            "s/call": fmt(tn),
            "evals/s": fmt(W / tn),
        },
    ]
    print(f"\n## 1. log-probability, cu5 (d = {post.dim}, {post.Z_H.shape[0]} band frequencies)")
    print(table(rows))

    # 2. moves on a small case -------------------------------------------------------------
    from helpers_fit import random_truth, synthetic_frf

    truth = random_truth(2, seed=3)
    sfrf = synthetic_frf(truth, rel_noise=1e-3, seed=4)
    snls = fit_nls(sfrf, weight="noise", f_max_hz=None).raise_if_failed()
    spost = make_log_posterior(sfrf, snls.scale, f_max_hz=None)
    slp = laplace_posterior(spost, initial_point(spost, snls))
    sm, sc = slp.mean, slp.cov
    rows = []
    for moves in ("de", "de_mix", "stretch"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ShortChainWarning)
            ps = sample_posterior(
                spost, (sm, sc), n_steps=1500 if QUICK else 4000, moves=moves, seed=0
            )
        d = ps.diagnostics
        rows.append({"moves": moves, "steps": d["n_steps"], "acc": fmt(d["acceptance_fraction"]),
                     "tau_max": fmt(d["tau_max"]), "steps/tau": fmt(d["steps_over_tau"]),
                     "ESS_min": fmt(d["ess_min"]), "wall_s": fmt(d["wall_s"]),
                     "ESS/s": fmt(d["ess_per_s"])})  # fmt: skip
    print(f"\n## 2. emcee moves, n = 2 second-order truth (d = {spost.dim}), Laplace start")
    print(table(rows))

    # 3. cu5 emcee to 50 tau -----------------------------------------------------------------
    t = time.perf_counter()
    with warnings.catch_warnings(record=True) as wlist:
        warnings.simplefilter("always", ShortChainWarning)
        ps = sample_posterior(post, (mean, cov), n_steps=3000 if QUICK else None, seed=0,
                              max_steps=60000, check_every=5000)  # fmt: skip
    d = ps.diagnostics
    print(f"\n## 3. emcee on cu5 (DE, d = {post.dim}, {d['n_walkers']} walkers), total "
          f"{time.perf_counter() - t:.1f} s incl. Laplace start")  # fmt: skip
    print(table([{"steps": d["n_steps"], "acc": fmt(d["acceptance_fraction"]), "tau_max": fmt(d["tau_max"]),
                  "tau_median": fmt(float(np.median(d["tau"]))), "steps/tau": fmt(d["steps_over_tau"]),
                  "ESS_min": fmt(d["ess_min"]), "wall_s": fmt(d["wall_s"]), "ESS/s": fmt(d["ess_per_s"]),
                  ">=50tau": d["converged_50tau"]}]))  # fmt: skip
    for w in wlist:
        print("warning:", w.message)
    top = np.argsort(d["tau"])[::-1][:6]
    print("largest tau: " + ", ".join(f"{ps.names[i]} {d['tau'][i]:.0f}" for i in top))
    tau = ps.tau
    print(f"posterior tau_H: median {np.median(tau[:, 0]):.3f} (5-95 %: {np.quantile(tau[:, 0], .05):.3f}-"
          f"{np.quantile(tau[:, 0], .95):.3f}); tau_M: median {np.median(tau[:, 1]):.3f}")  # fmt: skip

    # 4 + 5. robust checks ------------------------------------------------------------------
    omega = robust_omega(1000)
    g = Compensator.paper()
    models = {"WLS": wls(frf), "NLS": nls.model}
    poses = [dev.pose.moved(*o) for o in TRAIN_OFFSETS]  # ±4 cm along each axis
    labels, Pdev = device_plants(dev, omega, poses=poses, n_subjects=10, key=0)
    rows = []
    for name, m in models.items():
        t = time.perf_counter()
        # disk margin and T peak are printed: metrics="all"
        rep = robust_check(ps, (m, g), omega, max_samples=1000, metrics="all")
        dt = time.perf_counter() - t
        devrep = robust_check(Pdev, (m, g), omega, labels=labels, metrics="all")
        for what, r, tt in (("posterior (1000)", rep, dt), ("device (17)", devrep, None)):
            s = r.numbers()
            rows.append({"design": name, "plants": what, "P(stable)": fmt(s["p_stable"]),
                         "GM q05/q50 dB": f"{fmt(s['gm_db_q05'])}/{fmt(s['gm_db_q50'])}",
                         "PM q05/q50 deg": f"{fmt(s['pm_deg_q05'])}/{fmt(s['pm_deg_q50'])}",
                         "disk q05/q50": f"{fmt(s['disk_margin_q05'])}/{fmt(s['disk_margin_q50'])}",
                         "iso-bw q05/q50 Hz": f"{fmt(s['iso_bandwidth_hz_q05'])}/{fmt(s['iso_bandwidth_hz_q50'])}",
                         "Tpeak q95/q50 dB": f"{fmt(s['t_peak_db_q05'])}/{fmt(s['t_peak_db_q50'])}",
                         "passed": s["passed"], "worst": s["worst_label"] or s["worst_index"],
                         "time_s": fmt(tt) if tt else "-"})  # fmt: skip
    print("\n## 4–5. robust check, paper g, WLS- vs NLS-designed G (1000 freqs, 0.05–450 Hz)")
    print(table(rows))
    t = time.perf_counter()
    rv = robust_check(ps, (nls.model, g), omega, max_samples=1000, vectorize=True)
    print(
        f"vmapped variant (vectorize=True): {time.perf_counter() - t:.1f} s, P(stable) {rv.p_stable}"
    )

    # 6. pose study -------------------------------------------------------------------------
    t = time.perf_counter()
    rows = pose_study(dev, nominal_model=nls.model, omega=omega)
    print(f"\n## 6. pose study (7 poses, paper g), {time.perf_counter() - t:.1f} s")
    keys = ("nominal_stable", "nominal_iso_bandwidth_hz", "nominal_gm_db", "nominal_pm_deg",
            "reidentified_stable", "reidentified_iso_bandwidth_hz", "reidentified_gm_db", "reidentified_pm_deg")  # fmt: skip
    print(table([{"d (m)": f"({r['dx']:+.2f},{r['dy']:+.2f},{r['dz']:+.2f})"}
                 | {k.replace("reidentified", "reid"): fmt(r[k]) for k in keys}
                 for r in (row.flat() for row in rows)]))  # fmt: skip


class _Tee(io.StringIO):
    def write(self, s):
        sys.__stdout__.write(s)
        return super().write(s)


def run(quick: bool = False, out: str = "out/bench") -> Section:
    """The sections above as one report section (their printed markdown, headings demoted)."""
    sec = Section("Uncertainty: log-prob, emcee moves and chains, robust check, poses")
    buf = _Tee()
    with contextlib.redirect_stdout(buf):
        _body()
    sec.markdown = buf.getvalue().replace("\n## ", "\n### ")
    return sec


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    return standalone(run, __doc__, [a for a in argv if a != "--full-chain"])


if __name__ == "__main__":
    main()
