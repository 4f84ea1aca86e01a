"""Sample ML vs the FRF fits on a noisy protocol run, against the TRUE sampled plant (issue 17).

    python benchmarks/ml_noisy.py DEVICE [--noise 10] [--floor 0.3] [--periods 6] [--seed 0]

DEVICE is a preset (cu5, tripod3, hexapod6). ``--noise k`` multiplies the default force noise
(5 mN) and sets the encoder noise to k × 2 µm (the default encoder resolution; the default
encoder noise is 0, so ``--noise 1`` keeps it at 0). Prints, for the paper's WLS + positize,
NLS (relative and noise weights) and ML (``model_floor`` φ, ``pd_eps`` 1e-3): the P·P̂⁻¹ band
over 1–30 Hz against the true plant and against the measured P, closed-RHP roots of
det Ẑ_H / det Ẑ_T, and for ML its status, σ̂² and the Cramér–Rao band (median over
N(θ̂, CRB), P̂⁻¹ linearized). φ = 0.3 was chosen on cu5 (1× and 10×); tripod3 and hexapod6
were held out.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import hapid  # noqa: F401
from hapid.device import preset
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.fit import crb_band_db, crhp_report, fit_ml, fit_nls, positize, pphat_band_db, wls


def main(argv=None):
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("device")
    p.add_argument("--noise", type=float, default=10.0)
    p.add_argument("--floor", default="0.3", help="comma list of model floors φ")
    p.add_argument("--periods", type=int, default=6)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--pd-eps", type=float, default=1e-3)
    a = p.parse_args(argv)
    warnings.simplefilter("ignore")
    dev = preset(a.device)
    pn = 0.0 if a.noise == 1.0 else 2e-6 * a.noise
    prot = Protocol(n_periods=a.periods, force_noise=5e-3 * a.noise, position_noise=pn, seed=a.seed)
    run = periodic_run(dev, prot)
    frf = estimate_frf(run)
    w = np.asarray(frf.omega)
    P_true = np.asarray(dev.sampled_P(w))
    print(f"{a.device}: force noise {prot.force_noise:g} N, encoder noise {pn:g} m, "
          f"{a.periods} periods, seed {a.seed}")  # fmt: skip
    print("| estimator | band vs TRUE P (dB) | band vs measured P (dB) | CRHP H/T | notes |")
    print("|---|---|---|---|---|")

    def row(name, model, note=""):
        lo, hi = (float(x) for x in pphat_band_db(P_true, model, w, 30.0))
        lm, hm = (float(x) for x in pphat_band_db(frf.P, model, w, 30.0))
        c = crhp_report(model)
        print(
            f"| {name} | {lo:+.1f} / {hi:+.1f} | {lm:+.1f} / {hm:+.1f} | {int(c.hand)}/{int(c.total)} | {note} |"
        )

    row("paper WLS + positize", positize(wls(frf)))
    nls = fit_nls(frf)
    row("NLS relative (default)", nls.model, nls.status)
    try:
        nn = fit_nls(frf, weight="noise")
        row("NLS noise weights", nn.model, nn.status)
    except ValueError as e:  # noise-free Z_T (exact commands, no encoder noise)
        print(f"| NLS noise weights | — | — | — | {e} |")
    for phi in (float(x) for x in a.floor.split(",")):
        t = time.perf_counter()
        r = fit_ml(run, nls, model_floor=phi, pd_eps=a.pd_eps)
        dt = time.perf_counter() - t
        lo, hi = crb_band_db(r.model, r.crb, r.scale, w)
        row(f"ML φ={phi:g}", r.model, f"{r.status}, {int(r.n_steps)} steps, σ̂² {float(r.sigma2):.3g}, "
            f"Cramér–Rao band {lo:+.2f} / {hi:+.2f} dB, {dt:.1f} s")  # fmt: skip


if __name__ == "__main__":
    main()
