"""The single ``hapid`` commands a design stands for.

Each design stage is one of the eight commands a user would otherwise type (``frf``, ``fit``
×3, ``posterior``, ``robust``, ``tune``): :func:`commands` builds their argument lists from
the design options, with the files named as ``hapid design`` writes them in its output
folder (``frf.npz``, ``wls.npz``, …) and the input as the token :data:`INPUT`. A stage parses
its argument list with the real ``hapid`` parser, so every option it does not set has the
single command's default: the report's numbers are the single commands' numbers.
"""

from __future__ import annotations

import dataclasses
import shlex

from ..defaults import FIT_BAND_HZ, N_DRAWS

INPUT = "INPUT"  # the input file's token in a command's argument list

#: every stage of a design, in order (``--skip`` / ``--only`` take these names)
STAGES = ("frf", "wls", "nls", "ml", "posterior", "robust", "tune")
#: the stages that need the haptic hand/total pair (not a single impedance)
PAIR_ONLY = ("ml", "posterior", "robust", "tune")

#: output files: stage → file name in the output folder
FILES = {"frf": "frf.npz", "wls": "wls.npz", "nls": "nls.npz", "ml": "ml.npz",
         "posterior": "samples.npz", "robust": "robust.json", "tune": "design.npz"}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class DesignOptions:
    """What ``hapid design`` was asked for.

    Attributes:
        kind: the input's file kind (``run``, ``frf``, ``timeseries``, ``impedance_frf``).
        f_max_hz: upper band edge (Hz) of the NLS and ML fits and of the posterior; None:
            :data:`hapid.defaults.FIT_BAND_HZ` on the haptic pair, every frequency for a single impedance.
        posterior: ``"laplace"`` (default, seconds) or ``"emcee"``.
        samples: Laplace draws of the posterior.
        max_samples: loop draws of the robust check.
        seed: seed of the posterior and the tuner.
        fs_hz: the controller's sampling rate (Hz) for the tuner's evidence, or None
            (continuous).
        lab: extra ``hapid frf`` options for a lab time series (e.g. ``--response
            acceleration``).
    """

    kind: str
    f_max_hz: float | None = None
    posterior: str = "laplace"
    samples: int = 4000
    max_samples: int = N_DRAWS
    seed: int = 0
    fs_hz: float | None = None
    lab: tuple[str, ...] = ()

    @property
    def single(self) -> bool:
        """A single impedance (a lab time series or an impedance FRF): no controller."""
        return self.kind in ("timeseries", "impedance_frf")


def commands(o: DesignOptions) -> dict[str, list[str]]:
    """``{stage: argv}`` of the single commands (``frf`` is absent when the input already is
    an FRF; ``ml`` only for a run file; the pair-only stages absent for a single impedance)."""
    f_max_hz = FIT_BAND_HZ if o.f_max_hz is None and not o.single else o.f_max_hz
    f_max = [] if f_max_hz is None else ["--f-max-hz", f"{f_max_hz:g}"]
    out: dict[str, list[str]] = {}
    if o.kind == "run":
        out["frf"] = ["frf", INPUT, "--out", FILES["frf"]]
    elif o.kind == "timeseries":
        out["frf"] = ["frf", INPUT, "--h1", *o.lab, "--out", FILES["frf"]]
    src = FILES["frf"] if "frf" in out else INPUT
    out["wls"] = ["fit", src, "--method", "wls", "--positize", "--out", FILES["wls"]]
    out["nls"] = ["fit", src, "--method", "nls", *f_max, "--out", FILES["nls"]]
    if o.single:
        return out
    if o.kind == "run":
        out["ml"] = ["fit", INPUT, "--method", "ml", *f_max, "--out", FILES["ml"]]
    out["posterior"] = ["posterior", src, "--method", o.posterior, *f_max, "--seed", str(o.seed),
                        "--samples", str(o.samples), "--out", FILES["posterior"]]  # fmt: skip
    models = [x for m in ("wls", "nls", "ml") if m in out for x in ("--model", FILES[m])]
    out["robust"] = ["robust", "--frf", src, *models, "--max-samples", str(o.max_samples),
                     "--out", FILES["robust"]]  # fmt: skip
    fs = [] if o.fs_hz is None else ["--fs", f"{o.fs_hz:g}"]
    out["tune"] = ["tune", "--model", FILES["nls"], "--samples", FILES["posterior"], *fs,
                   "--seed", str(o.seed), "--out", FILES["tune"], "--report", "tune.json"]  # fmt: skip
    return out


def analyze_command(o: DesignOptions) -> list[str] | None:
    """The ``hapid analyze`` command that checks the design file on the measured FRF."""
    if o.single:
        return None
    src = FILES["frf"] if o.kind in ("run", "timeseries") else INPUT
    fs = ["--continuous"] if o.fs_hz is None else ["--fs", f"{o.fs_hz:g}"]
    return ["analyze", "--model", FILES["nls"], "--design", FILES["tune"], "--frf", src, *fs]


def resolve(argv: list[str], files: dict[str, str], input_path: str) -> list[str]:
    """``argv`` with the input token and the design's file names replaced by real paths
    (``files``: name → path)."""
    return [input_path if t == INPUT else files.get(t, t) for t in argv]


def shell_line(argv: list[str], input_path: str) -> str:
    """The command as a user types it (``hapid …``, the input's path in place)."""
    return "hapid " + " ".join(shlex.quote(input_path if t == INPUT else t) for t in argv)
