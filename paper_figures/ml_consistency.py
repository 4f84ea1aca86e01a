"""Consistency of the sample ML estimator against FRF-based fits (issue 17).

    python paper_figures/ml_consistency.py [--out out/ml] [--seeds 8] [--periods 4,8,16,32,64]

A strictly second-order 2-rod device (``SecondOrderDevice``), Hadamard patterns, ten
frequencies 1–40 Hz, noise on BOTH the force sensor and the encoder. For each number of
periods and noise seed: ``fit_ml`` on the run, and the FRF fits (paper WLS, NLS with relative
and with noise weights) on ``estimate_frf`` of the same run. Prints the rms (over seeds)
largest relative error of M, B, K (hand and total), its mean-over-seeds part (bias) and
draws ``out/ml_consistency.png`` (log-log, with a 1/√P reference line).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import hapid  # noqa: E402,F401
from hapid.device import SecondOrderDevice  # noqa: E402
from hapid.experiment import Protocol, periodic_run  # noqa: E402
from hapid.fit import ESTIMATORS, fit_estimators, model_relative_errors  # noqa: E402

FREQ_HZ = (1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0, 40.0)


def device() -> SecondOrderDevice:
    from helpers_fit import random_truth

    t = random_truth(2, 5)
    return SecondOrderDevice(hand=t.hand, mechanism=t.mechanism)


def _flat(model):
    return np.concatenate([np.ravel(np.asarray(a)) for a in (model.hand.M, model.hand.B, model.hand.K,
                           model.total.M, model.total.B, model.total.K)])  # fmt: skip


def errors(periods, seeds, force_noise, position_noise):
    """Per estimator: (rms over seeds of max rel. error, relative bias of the flat parameters)."""
    dev = device()
    truth = _flat(dev.model)
    res = {k: ([], []) for k in ESTIMATORS}
    for seed in seeds:
        prot = Protocol(freq_hz=FREQ_HZ, n_periods=periods, force_noise=force_noise,
                        position_noise=position_noise, encoder_resolution=0.0, seed=seed,
                        pattern="hadamard")  # fmt: skip
        fits = fit_estimators(periodic_run(dev, prot, hold="bandlimited"), f_max_hz=None)
        for k, m in fits.models().items():
            res[k][0].append(float(np.max(model_relative_errors(m, dev.model))))
            res[k][1].append(_flat(m))
    out = {}
    for k, (e, flat) in res.items():
        bias = np.linalg.norm(np.mean(flat, axis=0) - truth) / np.linalg.norm(truth)
        out[k] = (float(np.sqrt(np.mean(np.square(e)))), float(bias))
    return out


def main(argv=None):
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--out", default="out/ml")
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--periods", default="4,8,16,32,64")
    p.add_argument("--force-noise", type=float, default=0.05)
    p.add_argument("--position-noise", type=float, default=2e-5)
    a = p.parse_args(argv)
    warnings.simplefilter("ignore")
    periods = [int(x) for x in a.periods.split(",")]
    rows = {P: errors(P, range(a.seeds), a.force_noise, a.position_noise) for P in periods}
    names = list(rows[periods[0]])
    print(f"force noise {a.force_noise} N, position noise {a.position_noise} m per sample, "
          f"{a.seeds} seeds; rms max rel. error of M, B, K (bias = ‖mean − truth‖/‖truth‖)")  # fmt: skip
    print("| periods | " + " | ".join(f"{n} rms (bias)" for n in names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for P in periods:
        print(
            f"| {P} | "
            + " | ".join(f"{rows[P][n][0]:.2e} ({rows[P][n][1]:.1e})" for n in names)
            + " |"
        )
    ml = [rows[P]["ML"][0] for P in periods]
    slope = np.polyfit(np.log(periods), np.log(ml), 1)[0]
    print(f"ML rms error vs periods: log-log slope {slope:.2f} (1/√P: −0.5)")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 3.8))
    for i, n in enumerate(names):
        ax.loglog(
            periods, [rows[P][n][0] for P in periods], "o-", color=f"C{i}", label=f"{n} (rms)"
        )
        ax.loglog(periods, [rows[P][n][1] for P in periods], "x:", color=f"C{i}", alpha=0.7)
    ref = ml[0] * np.sqrt(periods[0] / np.asarray(periods, float))
    ax.loglog(periods, ref, "k--", lw=0.8, label="1/√P")
    ax.set_xlabel("periods P")
    ax.set_ylabel("max rel. error of M, B, K (x: bias)")
    ax.set_title("second-order device, noise on force and position", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    Path(a.out).mkdir(parents=True, exist_ok=True)
    path = Path(a.out) / "ml_consistency.png"
    fig.savefig(path, dpi=120)
    print(f"figure → {path}")


if __name__ == "__main__":
    main()
