"""Calibration of ``hapid predict``'s 90 % band of P along the command-line route, for both
draw constructions.

Per device: ``hapid simulate`` (the default protocol) → ``hapid frf`` → ``hapid posterior
--method laplace`` (its defaults: gp_corr model error, the ``hapid fit`` NLS fit with the
PSD-boundary refit and held boundary matrices) → ``hapid predict --draws params`` and
``--draws loop_gp`` on 200 log-spaced frequencies in 1–40 Hz; the true sampled P of the
device (what ``hapid plant`` writes; ``--truth continuous``: the continuous-time P, which
the measured FRF is not — ZOH and sampling add ~ωT/2 of phase lag) is compared at the frequencies ≥ 5 % away from every
experiment frequency, with :func:`hapid.uncertainty.band_calibration` (coverage of the 90 %
ball around the draws' median; its median radius over the median actual error; the same
ratio for a draw standing in for the truth, ``calibrated``).

Devices: the held-out family of ``benchmarks/calibrate_predictive.py`` (cu5_soft, cu5 with a
2-sample delay, tripod3 with rod compliance ×3, hexapod6 with a 2-sample delay, quad4).
This route differs from that benchmark's (its own protocol noise, a plain NLS fit): it is the
route a user takes.

Run:  PYTHONPATH=. python benchmarks/calibrate_predict_cli.py [--draws 200] [--samples 400]
      [--method laplace|emcee]
      [--devices cu5_soft,cu5_d2,tripod3_c3,hexapod6_d2,quad4]
Prints a markdown table.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import numpy as np

from hapid.cli import main as hapid
from hapid.io import load_frf
from hapid.pipeline._experiment import base_device

TWO_PI = 2.0 * np.pi
DEVICES = {  # name: (preset, --delay, --rod-compliance)
    "cu5_soft": ("cu5_soft", None, None),
    "cu5_d2": ("cu5", 2, None),
    "tripod3_c3": ("tripod3", None, 3.0),
    "hexapod6_d2": ("hexapod6", 2, None),
    "quad4": ("quad4", None, None),
    "cu5": ("cu5", None, None),  # a development device (not in the default list)
    "cu5_c2": ("cu5", None, 2.0),  # compliant cu5 (not in the default list)
    # the second held-out family of calibrate_predictive.py (written before any run of it)
    "tripod3_d1c2": ("tripod3", 1, 2.0),
    "quad4_d2": ("quad4", 2, None),
    "cu5_d2c2": ("cu5", 2, 2.0),
    "hexapod6_c2": ("hexapod6", None, 2.0),
}
HELD_OUT = "cu5_soft,cu5_d2,tripod3_c3,hexapod6_d2,quad4"
HELD_OUT_2 = "tripod3_d1c2,quad4_d2,cu5_d2c2,hexapod6_c2"
HELD_OUT_3 = ("tripod3:delay=3,quad4:delay=1:compliance=2,cu5:delay=3:move=0,0,0.01,"
              "hexapod6:delay=3,hexapod6:move=0.01,0,0")  # fmt: skip
"""The third held-out family of calibrate_predictive.py, as device specs (a name with ``:``
is ``preset[:delay=S][:compliance=F][:move=dx,dy,dz]``, calibrate_robust.parse_device)."""


def _spec(name: str):
    """``(hapid simulate's device options, the true device)`` of a device name or spec."""
    if ":" in name:
        from calibrate_robust import parse_device, spec_cli_args

        return spec_cli_args(name), parse_device(name)
    pre, delay, comp = DEVICES[name]
    variant = (["--delay", delay] if delay is not None else []) + (
        ["--rod-compliance", comp] if comp is not None else []
    )
    dev = base_device({"preset": pre, "delay_samples": delay, "rod_compliance": comp})
    return [pre, *variant], dev


def _run(argv):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = hapid([str(a) for a in argv])
    if rc != 0:
        raise RuntimeError(f"hapid {' '.join(map(str, argv))} exited {rc}")
    return out.getvalue()


def calibrate(name: str, d: Path, draws: int, samples: int, truth: str = "sampled",
              n_freq: int = 200, held_out: bool = True, method: str = "laplace",
              split_hz: float | None = None):  # fmt: skip
    from calibrate_predictive import split_figures

    device_args, dev = _spec(name)
    t0 = time.perf_counter()
    _run(["simulate", "--device", *device_args, "--out", d / "run.npz"])
    _run(["frf", d / "run.npz", "--out", d / "frf.npz"])
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            how = ["--samples", samples] if method == "laplace" else []  # emcee: to 50 τ
            _run(["posterior", d / "frf.npz", "--method", method, *how,
                  "--out", d / "samples.npz"])  # fmt: skip
        except RuntimeError as e:  # hapid posterior failed: say so in the table
            return [{"device": name, "failed": f"{e}: {err.getvalue().strip()}"}]
    t_post = time.perf_counter() - t0
    f_exp = np.asarray(load_frf(d / "frf.npz").omega) / TWO_PI
    rows = []
    for family in ("params", "loop_gp"):
        out = d / f"draws_{family}.npz"
        t0 = time.perf_counter()
        _run(["predict", "--samples", d / "samples.npz", "--draws", family, "--max-samples",
              draws, "--n-freq", n_freq, "--out", out])  # fmt: skip
        t_pred = time.perf_counter() - t0
        with np.load(out) as z:
            f, P = z["freq_hz"], z["P"]
        keep = np.min(np.abs(f[:, None] - f_exp[None]), axis=1) > 0.05 * f
        keep = keep if held_out else np.ones_like(keep)
        om = TWO_PI * f[keep]
        true_P = dev.sampled_P(om) if truth == "sampled" else dev.P(1j * om)
        for band, c, k in split_figures(P[:, keep], true_P, f[keep], split_hz):
            rows.append({"device": name, "draws": family, "band": band, "n_held_out": k, **c,
                         "posterior_s": t_post, "predict_s": t_pred})  # fmt: skip
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=200, help="hapid predict --max-samples")
    ap.add_argument("--samples", type=int, default=400, help="hapid posterior --samples")
    ap.add_argument("--devices", default=HELD_OUT,
                    help=f"device names or specs (default: the first held-out family; the second: "
                         f"{HELD_OUT_2}; the third: {HELD_OUT_3})")  # fmt: skip
    ap.add_argument("--method", choices=["laplace", "emcee"], default="laplace",
                    help="hapid posterior --method (emcee: the command's default, run to 50 τ; "
                    "--samples applies to laplace)")  # fmt: skip
    ap.add_argument("--truth", choices=["sampled", "continuous"], default="sampled",
                    help="the true P compared: sampled (ZOH at 1 kHz, what the experiment "
                    "measures and hapid plant writes) or the continuous-time P")  # fmt: skip
    ap.add_argument("--n-freq", type=int, default=200, help="hapid predict --n-freq (1–40 Hz)")
    ap.add_argument("--all-frequencies", action="store_true",
                    help="compare at every predicted frequency, not only the held-out ones")  # fmt: skip
    ap.add_argument("--split-hz", type=float, default=None,
                    help="also give each band's figures below and at or above this frequency "
                         "(Hz): where it is wide or short")  # fmt: skip
    a = ap.parse_args(argv)
    print(f"route: simulate → frf → posterior --method {a.method} → predict; 90 % band of P; "
          f"{'all' if a.all_frequencies else 'held-out'} frequencies of {a.n_freq} in 1–40 Hz; "
          f"truth: {a.truth} P\n")  # fmt: skip
    print("| device | draws | band | compared freqs | coverage | width / error | calibrated | "
          "rel. error of median | rel. radius | simulate→posterior s | predict s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    from calibrate_robust import split_specs

    for name in split_specs(a.devices):
        with tempfile.TemporaryDirectory() as tmp:
            for r in calibrate(name, Path(tmp), a.draws, a.samples, a.truth, a.n_freq,
                               not a.all_frequencies, a.method, a.split_hz):  # fmt: skip
                if "failed" in r:
                    print(f"| {r['device']} | — | {r['failed']} |", flush=True)
                    continue
                print(f"| {r['device']} | {r['draws']} | {r['band']} | {r['n_held_out']} | {r['coverage']:.3f} | "
                      f"{r['width_ratio']:.2f} | {r['width_ratio_calibrated']:.2f} | "
                      f"{r['rel_error_median']:.4f} | {r['rel_radius_median']:.4f} | "
                      f"{r['posterior_s']:.1f} | {r['predict_s']:.1f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
