"""Does the leave-one-frequency-out check's remedy establish ``hapid predict``'s band?

:func:`hapid.uncertainty.holdout_check` names the intervals between measured frequencies
where the params band is *not established* and frequencies to measure there
(``HoldoutCheck.suggested_hz``). This script follows that advice on a device: it runs the
paper's protocol (periodic steady state, force noise 5e-3), the NLS fit (relative weights,
≤ 40 Hz), the gp_corr Laplace posterior (200 draws) and the check; when the check flags
something, it measures again with the suggested frequencies added, repeats the fit,
posterior and check, and compares each round's band with the device's true sampled P at
1–40 Hz frequencies at least 0.2 Hz from every frequency that round measured
(:func:`held_out`): coverage / width ÷ error (frequencies) over 1–40 Hz, at 16–40 Hz (with
the medians of the error and the radius relative to ‖P‖), and at 16–40 Hz where the check
leaves the band established (:func:`calibrate_predictive.split_figures`).
It repeats until the check establishes the band or ``--rounds`` re-measurements were made.

Run:  PYTHONPATH=benchmarks:. python benchmarks/predict_remedy.py
      [--devices "hexapod6:compliance=2,hexapod6:delay=3"] [--seeds 0,1,2] [--draws 200]
      [--rounds 3]
Prints a markdown table.
"""

from __future__ import annotations

import argparse

import numpy as np
from calibrate_predictive import TWO_PI, device, fit, log_posterior, split_figures, truth
from calibrate_robust import split_specs

from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.uncertainty import (
    holdout_check,
    model_error_from,
    posterior_laplace_samples,
    predictive_plants,
)

DEVICES = ("hexapod6:compliance=2,hexapod6:delay=3,hexapod6:move=0.01,0,0,"
           "hexapod6:delay=1:compliance=3")  # fmt: skip
"""The 6-rod devices of calibrate_predictive.py's families on which the check flagged every
seed (the second, third and fourth families)."""


def posterior(dev, proto, draws: int, seed: int):
    """``(frf, gp_corr Laplace samples)`` of ``dev`` measured with ``proto``."""
    frf = estimate_frf(periodic_run(dev, proto))
    nls = fit(frf)
    post = log_posterior(frf, nls, model_error_from("gp_corr"))
    return frf, posterior_laplace_samples(post, draws, nls, key=seed)


def held_out(freq_hz, gap_hz: float = 0.2) -> np.ndarray:
    """400 log-spaced frequencies in 1–40 Hz at least ``gap_hz`` away from every measured one
    (rad/s): a fixed distance, not :func:`calibrate_predictive.held_out_grid`'s 5 %, so that
    a densely re-measured band keeps frequencies to judge."""
    f = np.geomspace(1.0, 40.0, 400)
    keep = np.min(np.abs(f[:, None] - np.asarray(freq_hz)[None]), axis=1) > gap_hz
    return TWO_PI * f[keep]


def run(spec: str, seed: int, draws: int, rounds: int, extra_hz=()) -> list[dict]:
    """One row per measurement round: the check, the frequencies it suggests, and the band's
    figures (``split_figures``) at the held-out frequencies of that round (:func:`held_out`).
    ``extra_hz``: frequencies (Hz, on the 1 Hz grid) measured from the first round on, besides
    the protocol's own."""
    dev = device(spec)
    proto = Protocol(seed=seed, force_noise=5e-3, pattern="paper" if dev.n >= 3 else "hadamard")
    if extra_hz:
        proto = Protocol(seed=seed, force_noise=5e-3, pattern=proto.pattern,
                         freq_hz=tuple(sorted(set(proto.freq_hz) | set(extra_hz))))  # fmt: skip
    runs = []
    for _ in range(rounds + 1):
        _, ps = posterior(dev, proto, draws, seed)
        chk = holdout_check(ps, max_samples=draws, seed=seed)
        runs.append((proto, ps, chk))
        if chk.ok or not chk.suggested_hz:  # established, or no grid point left to add
            break
        proto = Protocol(seed=seed, force_noise=5e-3, pattern=proto.pattern,
                         freq_hz=tuple(sorted(set(proto.freq_hz) | set(chk.suggested_hz))))  # fmt: skip
    rows = []
    for i, (p, ps, chk) in enumerate(runs):
        om = held_out(p.freq_hz)
        tr = truth(dev, om)["P"]
        P = predictive_plants(ps, om, max_samples=draws, seed=seed).P
        figs = {b: (c["coverage"], c["width_ratio"], k, c["rel_error_median"],
                    c["rel_radius_median"])
                for b, c, k in split_figures(P, tr, om / TWO_PI, 16.0, chk)}  # fmt: skip
        rows.append({"device": spec, "seed": seed, "round": i, "n_freq": len(p.freq_hz),
                     "check": chk, "figs": figs})  # fmt: skip
    return rows


def _gaps(chk) -> str:
    return ", ".join(f"{a:g}–{b:g}" for a, b in chk.not_established_hz) or "established"


def _fig(figs, band, rel: bool = False) -> str:
    if band not in figs:
        return "–"
    c, w, k, e, r = figs[band]
    return f"{c:.2f} / {w:.2f} ({k})" + (f"; {100 * e:.2f} % / {100 * r:.2f} %" if rel else "")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", default=DEVICES)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3,
                    help="at most this many re-measurements with the suggested frequencies")  # fmt: skip
    ap.add_argument("--extra-hz", default="",
                    help="comma-separated frequencies (Hz, 1 Hz grid) measured from the start, "
                         "e.g. a denser grid above 10 Hz; rounds then follow the check as before")  # fmt: skip
    a = ap.parse_args(argv)
    extra = tuple(float(x) for x in a.extra_hz.split(",") if x)
    print("| device | seed | round | measured frequencies | check (not established, Hz) | "
          "suggested (Hz) | all | ≥16 Hz; rel. error / rel. radius | est. ≥16 Hz |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for spec in split_specs(a.devices):
        for seed in (int(s) for s in a.seeds.split(",")):
            for r in run(spec, seed, a.draws, a.rounds, extra):
                chk, f = r["check"], r["figs"]
                sug = ", ".join(f"{x:g}" for x in chk.suggested_hz) or "–"
                print(f"| {spec} | {seed} | {r['round']} | {r['n_freq']} | {_gaps(chk)} | {sug} | "
                      f"{_fig(f, 'all')} | {_fig(f, '≥16 Hz', True)} | {_fig(f, 'est. ≥16 Hz')} |",
                      flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
