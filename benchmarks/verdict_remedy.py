"""Does a "not established" verdict's remedy establish it? The gap rule's cases, measured.

The gap rule (:func:`hapid.uncertainty._cover.gap_check`) calls a phase margin not established
when the draws' |PM| 5 % quantile clears the requirement by less than
:data:`~hapid.defaults.GAP_PM_DEG` at gain crossovers between two measured frequencies more
than :data:`~hapid.defaults.GAP_RATIO` apart, and names the band to measure. This script takes
the held-out controllers on which it fired (``calibrate_robust.py --family …``: the paper's g
scaled by α on a device variant), keeps the model and the controller fitted from the paper's
protocol, measures the FRF again with the remedy's frequencies added (11–14 Hz, inside the
10–15 Hz gap) and repeats the check (:func:`hapid.robust.loop_gp_check`, 200 loop draws, the
controller sampled at the device's rate). Printed per case: the true plant's PM and GM
(``true_plant_loop``), then the verdict and the draws' |PM| 5 % quantile on the paper's FRF
and on the denser one.

Run:  PYTHONPATH=. python benchmarks/verdict_remedy.py [--cases "tripod3:compliance=3@1,…"]
      [--extra-hz 11,12,13,14] [--draws 200]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import hapid  # noqa: F401,E402  (float64)

# the cases where the gap rule fired in calibrate_robust.py's held-out families (2026-12-05)
CASES = ("tripod3:compliance=3@0.6,tripod3:compliance=3@1,quad4:compliance=3@0.6,"
         "quad4:compliance=3@1,cu5:compliance=3@0.6,cu5:compliance=3@1,quad4:delay=1@0.6,"
         "quad4:move=0,0.01,0@0.6")  # fmt: skip


def run_case(spec: str, alpha: float, extra_hz, n_draws: int) -> dict:
    from calibrate_robust import parse_device

    from hapid import pipeline
    from hapid.control import Compensator
    from hapid.experiment import Protocol, estimate_frf, periodic_run
    from hapid.robust import loop_gp_check
    from hapid.tune._tune import scale_gain
    from hapid.tune._validate import true_plant_loop

    dev = parse_device(spec)
    g = scale_gain(Compensator.paper(), alpha)
    paper = Protocol(seed=0)
    fit = pipeline.control_fit(estimate_frf(periodic_run(dev, paper)), weight="relative",
                               f_max_hz=40.0).fit.result.raise_if_failed()  # fmt: skip
    truth = true_plant_loop(g, fit.model, dev).numbers()
    row = {"case": f"{spec} α={alpha:g}", "true_pm": truth["pm_deg"], "true_gm": truth["gm_db"]}
    for tag, freqs in (("paper", paper.freq_hz), ("remedy", paper.freq_hz + tuple(extra_hz))):
        frf = estimate_frf(periodic_run(dev, Protocol(seed=0, freq_hz=tuple(sorted(freqs)))))
        rep = loop_gp_check(frf, fit.model, g, n_draws=n_draws, seed=0, ts=dev.ts)
        row[tag] = (rep.check.verdict.value, rep.quantile("pm_deg", 0.05))
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--cases",
        default=CASES,
        help="comma-separated device@alpha (a device may itself contain commas)",
    )
    ap.add_argument("--extra-hz", default="11,12,13,14")
    ap.add_argument("--draws", type=int, default=200)
    a = ap.parse_args(argv)
    extra = [float(v) for v in a.extra_hz.split(",")]
    cases, buf = [], ""
    for part in a.cases.split(","):  # re-join device options that contain commas (move=)
        buf = part if not buf else f"{buf},{part}"
        if "@" in buf:
            spec, _, alpha = buf.rpartition("@")
            cases.append((spec, float(alpha)))
            buf = ""
    print(
        "| case | true PM ° / GM dB | paper FRF: verdict, PM q05 ° | "
        f"+ {a.extra_hz} Hz: verdict, PM q05 ° |"
    )
    print("|---|---|---|---|")
    for spec, alpha in cases:
        r = run_case(spec, alpha, extra, a.draws)
        print(f"| {r['case']} | {r['true_pm']:.1f} / {r['true_gm']:.1f} | {r['paper'][0]}, "
              f"{r['paper'][1]:.1f} | {r['remedy'][0]}, {r['remedy'][1]:.1f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
