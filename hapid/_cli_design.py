"""The ``hapid design`` command (the CLI shell: options in, :func:`hapid.design.run_design`,
the verdict table out). Registered by :mod:`hapid.cli`, which hands in its parser."""

from __future__ import annotations

from collections.abc import Callable

from . import design, io
from .defaults import N_DRAWS
from .design import STAGES, DesignOptions


class DesignCommandError(ValueError):
    """A bad ``hapid design`` input or option (one line, exit 2)."""


KINDS = ("run", "frf", "timeseries", "impedance_frf")


def _lab_args(a) -> tuple[str, ...]:
    out = ["--nperseg", str(a.nperseg), "--response", a.response, "--window", a.window]
    out += ["--sign", a.sign] if a.sign != "+" else []
    for opt, v in (
        ("--fs-hz", a.fs_hz),
        ("--f-min-hz", a.lab_f_min_hz),
        ("--f-max-hz", a.lab_f_max_hz),
    ):
        if v is not None:
            out += [opt, f"{v:g}"]
    return tuple(out)


def cmd_design(a, parse: Callable) -> None:
    kind = io.file_kind(a.input, "a run file, an FRF file or a lab time series")
    if kind not in KINDS:
        raise DesignCommandError(
            f"{a.input}: holds {'arrays hapid does not know' if kind == 'unknown' else f'a {kind} file'}; "
            "hapid design takes a run file (hapid simulate), an FRF file (hapid frf) or a lab "
            "time series (fs_hz, force, response)"
        )  # fmt: skip
    fs = a.fs
    if fs is None and kind == "run":
        fs = float(io.load_run(a.input).fs_hz)
    o = DesignOptions(kind=kind, f_max_hz=a.f_max_hz, posterior=a.posterior, samples=a.samples,
                      max_samples=a.max_samples, seed=a.seed, fs_hz=fs,
                      lab=_lab_args(a) if kind == "timeseries" else ())  # fmt: skip
    rep = design.run_design(a.input, a.out, o, parse, skip=tuple(a.skip or ()), only=tuple(a.only or ()),
                     cache_dir=None if a.no_cache else a.cache)  # fmt: skip
    n = rep.numbers
    for c in rep.checks:
        print(c.line())
    print(f"verdict: {rep.status}" + ("" if rep.checks else f" ({n['controller']})"))
    for m, q in n["fits"].items():
        band = q.get("pphat_band_db")
        print(f"{m}: " + (q.get("error") or q["status"])
              + ("" if not band else f"; P·P̂⁻¹ band to 30 Hz {band[0]:+.1f} / {band[1]:+.1f} dB"))  # fmt: skip
    st = n["stages"]
    print(f"stages computed: {', '.join(st['computed']) or '—'}; from cache: "
          f"{', '.join(st['cached']) or '—'}; skipped: {', '.join(st['skipped']) or '—'}")  # fmt: skip
    print(f"report → {rep.out_dir / 'report.html'}, {rep.out_dir / 'report.json'}")


def register(sub, parse: Callable) -> None:
    """The ``hapid design`` parser; ``parse(argv)`` parses a ``hapid`` command line."""
    d = sub.add_parser("design", help="one command: FRF, fits, posterior, robust check, tuned g, verdict, HTML report",
                       description="From a run file, an FRF file or a lab time series to fitted "
                       "models with their quality, the posterior, the robust check of the paper g "
                       "on every model, a tuned g with its certificate, the three-valued verdict "
                       "and the design file for hapid analyze --design; writes report.html "
                       "(self-contained), report.json, the figures (PNG, PDF) and every single "
                       "command's file into --out. Stages are cached: re-running with one option "
                       "changed recomputes only what depends on it.",
                       epilog="example: hapid design run.npz --out out/design")  # fmt: skip
    d.add_argument(
        "input", help="run file (hapid simulate), FRF file (hapid frf) or lab time series"
    )
    d.add_argument("--out", required=True, help="output folder")
    d.add_argument("--f-max-hz", type=float,
                   help="upper band edge (Hz) of the NLS and ML fits and of the posterior (default: "
                   "40 on the haptic pair, every frequency for a single impedance)")  # fmt: skip
    d.add_argument("--posterior", choices=["laplace", "emcee"], default="laplace",
                   help="posterior method: laplace (default, seconds) or emcee (minutes)")  # fmt: skip
    d.add_argument("--samples", type=int, default=4000, help="Laplace draws (default 4000)")
    d.add_argument(
        "--max-samples",
        type=int,
        default=N_DRAWS,
        help=f"robust check's loop draws (default {N_DRAWS})",
    )
    d.add_argument("--seed", type=int, default=0, help="seed of the posterior and the tuner")
    d.add_argument(
        "--fs",
        type=float,
        help="controller sampling rate (Hz); default: the run's, else continuous",
    )
    d.add_argument("--skip", action="append", choices=STAGES, metavar="STAGE",
                   help=f"leave out a stage and what needs it; repeatable ({', '.join(STAGES)})")  # fmt: skip
    d.add_argument("--only", action="append", choices=STAGES, metavar="STAGE",
                   help="run only this stage and what it needs; repeatable")  # fmt: skip
    d.add_argument("--cache", default=".hapid_cache/stages", help="stage cache folder")
    d.add_argument("--no-cache", action="store_true", help="recompute every stage")
    lab = d.add_argument_group("lab time series (as hapid frf)")
    lab.add_argument("--nperseg", type=int, default=2048, help="samples per Welch segment")
    lab.add_argument("--window", choices=["hann", "boxcar"], default="hann",
                     help="segment window (as hapid frf; default hann)")  # fmt: skip
    lab.add_argument("--response", choices=["displacement", "velocity", "acceleration"],
                     default="displacement", help="what the response channels measure "
                     "(as hapid frf; default displacement)")  # fmt: skip
    lab.add_argument("--sign", choices=["+", "-"], default="+",
                     help="+: Z = +F/x, -: Z = -F/x (as hapid frf; default +)")  # fmt: skip
    lab.add_argument(
        "--fs-hz", type=float, help="sampling rate of the records if the file has none"
    )
    lab.add_argument("--lab-f-min-hz", type=float, help="lowest frequency kept from the records")
    lab.add_argument("--lab-f-max-hz", type=float, help="highest frequency kept from the records")
    d.set_defaults(func=lambda a: cmd_design(a, parse))
