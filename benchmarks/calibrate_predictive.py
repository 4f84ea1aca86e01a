"""Calibration of the posterior-predictive band of P, Z_H, Z_T on misspecified devices.

For each device: simulate the paper's multisine experiments (periodic steady state, default
protocol), estimate the FRF, fit the NLS model (relative weights, ≤ 40 Hz), build the
posterior with the white and the GP model error, draw the predictive plant on a dense grid
of 1–40 Hz *excluding* the experiment frequencies (held out: ≥ 5 % away from any of them)
and compare with the device's true sampled response there
(:func:`hapid.uncertainty.band_calibration`: coverage of the 90 % credible ball around the
draws' median, its median radius over the median actual error, per-element re/im interval
coverage). Devices:

- ``cu5`` — the development device (two-layer hand, compliant chain, 1-sample delay);
- ``tripod3_d2`` — the second misspecified device, chosen *before* any tuning and never
  used to tune the likelihood: a 3-rod tripod with a 2-sample (2 ms) actuator delay;
- ``second_order`` — a strictly second-order n = 2 device (the model class is right).

Run:  PYTHONPATH=. python benchmarks/calibrate_predictive.py [--method laplace|emcee]
      [--draws 400] [--devices cu5,tripod3_d2,second_order]
Prints a markdown table.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import hapid
from hapid.device import SecondOrderDevice, preset
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.fit import fit_nls
from hapid.uncertainty import (
    ShortChainWarning,
    band_calibration,
    boundary_fixed,
    make_log_posterior,
    posterior_laplace_samples,
    predictive_plants,
    sample_posterior,
)

TWO_PI = 2.0 * np.pi


def _spd(rng, n, scale, cond=10.0):
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return Q @ np.diag(scale * np.geomspace(1.0 / cond, 1.0, n)) @ Q.T


def device(name: str):
    if name == "cu5":
        return preset("cu5")
    if name == "tripod3_d2":
        return preset("tripod3", delay_samples=2)
    if name == "second_order":
        rng = np.random.default_rng(0)
        hand = hapid.SecondOrder(_spd(rng, 2, 0.3), _spd(rng, 2, 10.0), _spd(rng, 2, 800.0))
        mech = hapid.SecondOrder(_spd(rng, 2, 0.6), _spd(rng, 2, 40.0), _spd(rng, 2, 200.0))
        return SecondOrderDevice(hand=hand, mechanism=mech, delay_samples=0)
    raise ValueError(name)


def held_out_grid(freq_hz, f_lo=1.0, f_hi=40.0, n=200):
    f = np.geomspace(f_lo, f_hi, n)
    keep = np.min(np.abs(f[:, None] - np.asarray(freq_hz)[None]), axis=1) > 0.05 * f
    return TWO_PI * f[keep]


def truth(dev, omega):
    if isinstance(dev, SecondOrderDevice):
        m = dev.model
        s = 1j * omega
        return {"Z_H": np.asarray(m.Z_H(s)), "Z_T": np.asarray(m.Z_T(s)), "P": np.asarray(m.P(s))}
    ZH, ZT = (np.asarray(a) for a in dev.sampled_impedances(omega))
    return {"Z_H": ZH, "Z_T": ZT, "P": np.asarray(dev.sampled_P(omega))}


def calibrate(name: str, kinds=("white", "gp"), method="laplace", draws=400, seed=0):
    dev = device(name)
    noise = 5e-3 if not isinstance(dev, SecondOrderDevice) else 2e-2
    pattern = "hadamard" if dev.n < 3 else "paper"  # the paper's pattern is singular for n = 2
    run = periodic_run(dev, Protocol(seed=seed, force_noise=noise, pattern=pattern))
    frf = estimate_frf(run)
    weight = "relative" if not isinstance(dev, SecondOrderDevice) else "noise"
    nls = fit_nls(frf, weight=weight, f_max_hz=40.0).raise_if_failed()
    om = held_out_grid(np.asarray(frf.omega) / TWO_PI)
    tr = truth(dev, om)
    rows = []
    for kind in kinds:
        fixed = boundary_fixed(nls) if nls.boundary else None
        post = make_log_posterior(
            frf, nls.scale, f_max_hz=40.0, model_error=kind, reference=nls, fixed=fixed
        )
        t0 = time.perf_counter()
        if method == "laplace":
            ps = posterior_laplace_samples(post, draws, nls, key=seed)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ShortChainWarning)
                ps = sample_posterior(post, nls, moves="laplace_de", seed=seed)
        t_post = time.perf_counter() - t0
        t0 = time.perf_counter()
        pred = predictive_plants(ps, om, max_samples=draws, seed=seed)
        t_pred = time.perf_counter() - t0
        for q in ("P", "Z_H", "Z_T"):
            c = band_calibration(pred[q], tr[q])
            rows.append({"device": name, "error model": kind, "quantity": q, **c,
                         "posterior_s": t_post, "predict_s": t_pred, "n_held_out": len(om)})  # fmt: skip
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", choices=["laplace", "emcee"], default="laplace")
    ap.add_argument("--draws", type=int, default=400)
    ap.add_argument("--devices", default="cu5,tripod3_d2,second_order")
    a = ap.parse_args(argv)
    print(f"posterior: {a.method}; 90 % predictive band; held-out frequencies in 1–40 Hz\n")
    print("| device | model error | quantity | coverage | width / error | element coverage | "
          "median rel. error of median | held-out freqs | posterior s | predict s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in a.devices.split(","):
        for r in calibrate(name, method=a.method, draws=a.draws):
            print(f"| {r['device']} | {r['error model']} | {r['quantity']} | {r['coverage']:.3f} | "
                  f"{r['width_ratio']:.2f} | {r['element_coverage']:.3f} | {r['rel_error_median']:.4f} | "
                  f"{r['n_held_out']} | {r['posterior_s']:.1f} | {r['predict_s']:.1f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
