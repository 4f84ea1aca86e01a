"""CLI commands ``hapid predict`` (posterior-predictive plant draws) and ``hapid plant``
(a simulated device's true plant as an FRF file). Registered by :mod:`hapid.cli`."""

from __future__ import annotations

import numpy as np

from ._constants import TWO_PI
from ._grids import log_grid_hz
from .defaults import FIT_BAND_HZ, FS_HZ


class CommandError(ValueError):
    """A bad option of `hapid predict` / `hapid plant` (one line, exit 2)."""


def _grid(a):
    """The log grid (Hz) of ``--f-min-hz/--f-max-hz/--n-freq`` (checked by hapid._cli_checks)."""
    return log_grid_hz(a.f_min_hz, a.f_max_hz, a.n_freq) / TWO_PI  # Hz


def cmd_predict(a):
    from . import io
    from .io import load_samples
    from .uncertainty import predictive_plants

    f = _grid(a)
    ps = load_samples(a.samples)
    d = predictive_plants(ps, TWO_PI * f, max_samples=a.max_samples, seed=a.seed,
                          include_error=not a.no_model_error)  # fmt: skip
    out = io.save_draws(a.out, f, {k: d[k] for k in ("P", "Z_H", "Z_T")})
    kind = "none" if a.no_model_error else ps.error_kind
    print(f"{d['P'].shape[0]} predictive draws of P (model error: {kind}) on {len(f)} frequencies "
          f"{f[0]:.4g}–{f[-1]:.4g} Hz → {out}")  # fmt: skip
    print(PREDICT_CALIBRATION_NOTE)


PREDICT_CALIBRATION_NOTE = (
    "note: these draws are calibrated only where they were checked: their 90 % band covered "
    "97–100 % of held-out frequencies on the devices that chose the settings (cu5, tripod3), "
    "but 36 % (width/error 0.7) on a held-out 5-rod device, where the second-order model class "
    "is wrong in other ways; above the fit band the draws are the model's own plant. For "
    "robustness use hapid robust's loop draws (conditioned on the measured FRF, checked with a "
    "three-valued verdict)"
)


def cmd_plant(a):
    from . import io
    from ._cli_device import describe, device_from_args
    from .frf import FRF

    f = _grid(a)
    dev = device_from_args(a, fs_hz=a.fs)
    if f[-1] >= 0.5 * dev.fs_hz:
        raise CommandError(
            f"--f-max-hz {f[-1]:g} must be below the Nyquist frequency {0.5 * dev.fs_hz:g} Hz"
        )
    ZH, ZT = (np.asarray(z) for z in dev.sampled_impedances(TWO_PI * f))
    out = io.save_frf(a.out, FRF(omega=TWO_PI * f, Z_H=ZH, Z_T=ZT))
    print(f"true sampled plant of {describe(a)} (Z_H, Z_T; no noise) on {len(f)} frequencies "
          f"{f[0]:.4g}–{f[-1]:.4g} Hz → {out}  (check a design: hapid analyze --frf {out} --fs {a.fs:g})")  # fmt: skip


_UNITS = (("_hz", "Hz"), ("_db", "dB"), ("_deg", "°"), ("_s", "s"))


def _unit(key: str) -> str:
    k = key.removesuffix("_q05").removesuffix("_q50")
    return next((u for suf, u in _UNITS if k.endswith(suf)), "")


def _fmt(v) -> str:
    if isinstance(v, bool | np.bool_) or v is None:
        return str(v)
    if isinstance(v, int | np.integer):
        return str(int(v))
    return f"{float(v):.4g}"


def recheck_table(start: dict, tuned: dict) -> str:
    """The ``hapid tune`` re-check as a text table: quantity, unit, start, tuned (4
    significant figures)."""
    rows = [
        (k, _unit(k), _fmt(start.get(k)), _fmt(tuned.get(k))) for k in tuned if k != "validate_s"
    ]
    w = max(len(r[0]) for r in rows) if rows else 10
    head = f"  {'quantity':{w}s}  {'unit':4s}  {'start g':>10s}  {'tuned g':>10s}"
    return "\n".join([head] + [f"  {a:{w}s}  {u:4s}  {b:>10s}  {c:>10s}" for a, u, b, c in rows])


def register(sub):
    pr = sub.add_parser("predict", help="posterior-predictive draws of the plant P (model error included)",
                        description="Draws of the true P = Z_H Z_T⁻¹ (and Z_H, Z_T) on any grid from a "
                        "posterior-samples file: parameter uncertainty plus the model-error term, "
                        "conditioned on the fit residuals (GP) or independent (white). Not "
                        "calibrated off the devices that chose the settings (36 %% coverage of the "
                        "90 %% band on a held-out 5-rod device): see docs/conventions.md.")  # fmt: skip
    pr.add_argument("--samples", required=True, help="posterior samples file (hapid posterior)")
    pr.add_argument("--f-min-hz", type=float, default=1.0, help="lowest frequency (Hz), default 1")
    pr.add_argument(
        "--f-max-hz", type=float, default=FIT_BAND_HZ, help="highest frequency (Hz), default 40"
    )
    pr.add_argument("--n-freq", type=int, default=200, help="log-spaced frequencies, default 200")
    pr.add_argument(
        "--max-samples", type=int, default=500, help="draws (random subset), default 500"
    )
    pr.add_argument("--no-model-error", action="store_true", help="parameter uncertainty only")
    pr.add_argument("--seed", type=int, default=0, help="seed of the subset and the error draws")
    pr.add_argument(
        "--out", required=True, help="output .npz: freq_hz (N,), P, Z_H, Z_T (S, N, n, n)"
    )
    pr.set_defaults(func=cmd_predict)

    pl = sub.add_parser("plant", help="write a simulated device's true plant as an FRF file",
                        description="The true sampled Z_H, Z_T (hence P) of a preset device as an FRF "
                        "file without noise, readable by hapid analyze --frf.")  # fmt: skip
    from ._cli_device import add_device_args

    add_device_args(pl)
    pl.add_argument(
        "--fs", type=float, default=FS_HZ, help=f"sampling rate (Hz), default {FS_HZ:g}"
    )
    pl.add_argument(
        "--f-min-hz", type=float, default=0.001, help="lowest frequency (Hz), default 0.001"
    )
    pl.add_argument(
        "--f-max-hz", type=float, default=499.99, help="highest frequency (Hz), default 499.99"
    )
    pl.add_argument("--n-freq", type=int, default=1500, help="log-spaced frequencies, default 1500")
    pl.add_argument("--out", required=True, help="output FRF file (.npz)")
    pl.set_defaults(func=cmd_plant)
