"""Benchmark the identification stage: WLS, WLS+positize, NLS per solver, jaxopt, scipy.

Usage: ``python benchmarks/bench_fit.py [--n 5] [--noise 1e-3] [--repeat 3] [--fig out.png]``

Cases: a synthetic strictly second-order truth (random SPD M, B, K; the paper's 28
frequencies; complex Gaussian noise relative to ‖Z‖) and, when ``hapid.device`` is importable,
the default simulated device ``cu5()`` (not second order: sensor compliance, extra modes,
delay). Every method fits the same FRF; times are the median of ``--repeat`` runs after a
warm-up call whose time (≈ compile) is reported separately. Columns: compile s, run s,
steps, P·P̂⁻¹ singular-value band over 1–30 Hz (dB, against the true plant), and for the
synthetic case the largest relative Frobenius error of M, B, K (hand and total).

scipy reference: ``scipy.optimize.least_squares`` (method "lm", MINPACK) on a plain-numpy
version of the same PD parameterization and relative-weight residual with the same start.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from importlib.metadata import version

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))

import jax  # noqa: E402

import hapid  # noqa: E402,F401
from hapid.fit import (  # noqa: E402
    crhp_report,
    data_scale,
    fit_nls,
    model_relative_errors,
    model_to_theta,
    positize,
    pphat_band_db,
    project_pd,
    theta_to_model,
    wls,
)
from hapid.frf import as_frf  # noqa: E402

FREQ_HZ = np.concatenate([np.arange(1.0, 11.0), np.arange(15.0, 101.0, 5.0)])


def _timed(fn, repeat):
    t = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t
    runs = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t)
    run = statistics.median(runs)
    return out, max(first - run, 0.0), run


# ---- plain numpy/scipy version of the NLS (relative weights, same θ layout) -------------
def _np_residual_factory(frf, f_max_hz, scale):
    w = np.asarray(frf.omega)
    keep = w <= 2 * np.pi * (np.inf if f_max_hz is None else f_max_hz) * (1 + 1e-12)
    s = 1j * w[keep] / float(scale.omega_ref)
    zr = float(scale.z_ref)
    ZH, ZT = np.asarray(frf.Z_H)[keep] / zr, np.asarray(frf.Z_T)[keep] / zr
    WH = 1 / np.linalg.norm(ZH, axis=(1, 2))[:, None, None]
    WT = 1 / np.linalg.norm(ZT, axis=(1, 2))[:, None, None]
    n = ZH.shape[-1]
    rows, cols = np.tril_indices(n)
    t = len(rows)
    s1, s2 = s[:, None, None], s[:, None, None] ** 2

    def mats(theta):
        out = []
        for k in range(6):
            L = np.zeros((n, n))
            L[rows, cols] = theta[k * t : (k + 1) * t]
            out.append(L @ L.T)
        return out

    def residual(theta):
        A = mats(theta)
        zh = A[0] * s2 + A[1] * s1 + A[2]
        zt = zh + A[3] * s2 + A[4] * s1 + A[5]
        e = np.stack([WH * (zh - ZH), WT * (zt - ZT)])
        return np.concatenate([e.real.ravel(), e.imag.ravel()])

    return residual


def _scipy_fit(frf, f_max_hz):
    from scipy.optimize import least_squares

    scale = data_scale(frf, f_max_hz)
    theta0 = np.asarray(model_to_theta(project_pd(wls(frf, f_max_hz=f_max_hz)), scale))
    res = least_squares(
        _np_residual_factory(frf, f_max_hz, scale), theta0, method="lm", xtol=1e-10, ftol=1e-10
    )
    return theta_to_model(res.x, scale), res.nfev, res.status > 0


def run_case(name, frf, P_true, truth, f_max_hz, repeat):
    w = frf.omega
    rows = []

    def add(method, model, compile_s, run_s, steps="", status=""):
        lo, hi = pphat_band_db(P_true, model, w, f_max_hz=30.0)
        err = float(np.max(model_relative_errors(model, truth))) if truth is not None else np.nan
        crhp = crhp_report(model)
        rows.append(
            dict(
                method=method,
                compile=compile_s,
                run=run_s,
                steps=steps,
                status=status,
                lo=float(lo),
                hi=float(hi),
                err=err,
                crhp=f"{int(crhp.hand)}/{int(crhp.total)}",
            )
        )

    m, c, r = _timed(lambda: wls(frf), repeat)
    add("wls (paper, all freqs)", m, c, r)
    m, c, r = _timed(lambda: positize(wls(frf)), repeat)
    add("wls + positize", m, c, r)
    for solver in ("lm", "dogleg", "gauss_newton", "bfgs", "nonlinear_cg", "jaxopt_lm"):
        for weight in ("relative", "paper"):
            res, c, r = _timed(
                lambda s=solver, wt=weight: fit_nls(
                    frf, f_max_hz=f_max_hz, solver=s, weight=wt, max_steps=3000
                ),
                repeat,
            )
            add(f"nls {solver} ({weight})", res.model, c, r, int(res.n_steps), res.status)
    t = time.perf_counter()
    model, nfev, ok = _scipy_fit(frf, f_max_hz)
    add(
        "scipy least_squares lm (relative)",
        model,
        0.0,
        time.perf_counter() - t,
        nfev,
        "ok" if ok else "fail",
    )

    band = "all" if f_max_hz is None else f"≤{f_max_hz:g} Hz"
    print(f"\n## {name}  (n = {frf.n}, fit band {band}; band column = P·P̂⁻¹ over 1–30 Hz)")
    print(
        f"{'method':36s} {'compile s':>9s} {'run s':>8s} {'steps':>6s} {'status':>10s} "
        f"{'PP̂⁻¹ band dB':>16s} {'max rel err':>11s} {'CRHP H/T':>8s}"
    )
    for row in rows:
        print(
            f"{row['method']:36s} {row['compile']:9.2f} {row['run']:8.4f} {row['steps']!s:>6s} "
            f"{row['status']:>10s} {row['lo']:+7.2f}/{row['hi']:+7.2f} {row['err']:11.2e} "
            f"{row['crhp']:>8s}"
        )
    return rows


def _synthetic(n, noise, seed=0):
    from helpers_fit import random_truth, synthetic_frf

    truth = random_truth(n, seed=seed)
    frf = synthetic_frf(truth, FREQ_HZ, rel_noise=noise, seed=seed + 1)
    return truth, frf, truth.P(1j * frf.omega)


def _cu5(noise, seed=0):
    from hapid.device import cu5

    dev = cu5()
    w = 2 * np.pi * FREQ_HZ
    ZH, ZT = (np.asarray(Z) for Z in dev.impedances(1j * w))
    rng = np.random.default_rng(seed)
    out = []
    for Z in (ZH, ZT):
        std = noise * np.linalg.norm(Z, axis=(1, 2))[:, None, None] / Z.shape[-1] * np.ones(Z.shape)
        e = (rng.standard_normal(Z.shape) + 1j * rng.standard_normal(Z.shape)) / np.sqrt(2)
        out += [Z + std * e, std]
    frf = as_frf(FREQ_HZ, out[0], out[2], out[1], out[3])
    return frf, np.asarray(dev.P(1j * w))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5)
    ap.add_argument("--noise", type=float, default=1e-3, help="relative complex noise std")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--fig", default=None, help="write a Pareto figure (time vs error) here")
    args = ap.parse_args(argv)

    print("# hapid fit benchmark")
    print(
        f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, {os.cpu_count()} cpus"
    )
    print(
        "versions: python "
        + platform.python_version()
        + ", "
        + ", ".join(
            f"{p} {version(p)}"
            for p in ("jax", "optimistix", "lineax", "equinox", "jaxopt", "scipy", "numpy")
        )
    )
    print(f"load average: {os.getloadavg()}")

    truth, frf, P = _synthetic(args.n, args.noise)
    all_rows = {"synthetic": run_case("synthetic second order", frf, P, truth, None, args.repeat)}
    try:
        frf_c, P_c = _cu5(args.noise)
    except ImportError as e:
        print(f"\n(cu5 skipped: {e})")
    else:
        all_rows["cu5"] = run_case("cu5 (simulated device)", frf_c, P_c, None, 40.0, args.repeat)

    if args.fig:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, len(all_rows), figsize=(6 * len(all_rows), 4.5), squeeze=False)
        for ax, (case, rows) in zip(axes[0], all_rows.items(), strict=True):
            for row in rows:
                y = row["err"] if case == "synthetic" else max(abs(row["lo"]), abs(row["hi"]))
                ax.loglog(max(row["run"], 1e-5), max(y, 1e-12), "o")
                ax.annotate(row["method"], (max(row["run"], 1e-5), max(y, 1e-12)), fontsize=6)
            ax.set_xlabel("run time after warm-up [s]")
            ax.set_ylabel(
                "max rel. error of M, B, K" if case == "synthetic" else "max |P·P̂⁻¹| dB, 1–30 Hz"
            )
            ax.set_title(case)
        fig.tight_layout()
        fig.savefig(args.fig, dpi=130)
        print(f"\nfigure: {args.fig}")


if __name__ == "__main__":
    main()
