"""The ``hapid`` command. Each subcommand is a thin shell over the library: parse, call,
write files, print a short report. Errors are one clear line (exit code 2), not a traceback;
set ``HAPID_DEBUG=1`` for the traceback."""

from __future__ import annotations

import argparse
import os
import sys
import warnings

from . import _distributed
from ._cli_analyze import FEW_FRF_FREQUENCIES, cmd_analyze  # noqa: F401  (the command's API)
from ._cli_device import add_device_args
from ._cli_errors import CLIError
from ._cli_help import annotate
from ._cli_kw import uncertified_warning  # noqa: F401  (part of the CLI's API)
from ._cli_measure import cmd_demo, cmd_fit, cmd_frf, cmd_simulate
from ._cli_processes import _PROCESSES_HELP
from ._cli_scene import cmd_paper, cmd_run, cmd_sweep
from ._cli_uq import cmd_posterior, cmd_robust, cmd_tune
from ._constants import TUNE_EXPECTED_S
from .defaults import (
    DRAWS,
    FIT_BAND_HZ,
    FS_HZ,
    GM_DB,
    N_DRAWS,
    NLS_MAX_STEPS,
    PM_DEG,
    TUNE_MAX_STEPS,
    TUNE_N_HOLDOUT,
    TUNE_N_SUBJECTS,
    TUNE_N_TRAIN,
    TUNE_QUANTILE,
)

EXAMPLES = """examples:
  hapid simulate --device cu5 --out run.npz            # the paper's protocol on cu5
  hapid simulate --device quad4 --delay 2 --out r4.npz # a 4-rod variant (--rod-compliance, --move)
  hapid frf run.npz --out frf.npz --plot frf.png       # empirical Z_H, Z_T (+ std)
  hapid fit frf.npz --method wls --positize --out wls.npz   # the paper's baseline
  hapid fit frf.npz --method nls --out nls.npz         # PD-constrained nonlinear fit
  hapid analyze --model nls.npz --device cu5 --out report.json
  hapid posterior frf.npz --out samples.npz            # emcee posterior over M, B, K
  hapid robust --samples samples.npz --model nls.npz --device cu5 --out robust.json
  hapid demo --out out/demo                            # simulate → FRF → σ plots
  hapid paper --out out/paper                          # the paper's figures 5–10 + summary
  hapid run scenes/zh_only.toml                        # a scene: only the stages it needs
  hapid design run.npz --out out/design                # fits, robust check, tuned g, verdict, report.html
"""


def _protocol_args(p):
    g = p.add_argument_group("protocol")
    g.add_argument("--freqs", default="paper",
                   help="excited frequencies in Hz: 'paper' (1..10, 15..100) or a comma list")  # fmt: skip
    g.add_argument("--fs", type=float, default=FS_HZ, help=f"sampling rate (Hz), default {FS_HZ:g}")
    g.add_argument(
        "--period", type=int, default=1000, help="period length in samples (default 1000)"
    )
    g.add_argument(
        "--periods", type=int, default=4, help="measured periods per experiment (default 4)"
    )
    g.add_argument("--transient", type=int, default=1, help="discarded periods (time domain)")
    g.add_argument("--pattern", default="paper", choices=["paper", "one_at_a_time", "hadamard"])
    g.add_argument("--phases", default="random", choices=["random", "schroeder", "min_crest"])
    g.add_argument("--amplitude", type=float, default=0.3, help="component amplitude a (N)")
    g.add_argument("--seed", type=int, default=0, help="seed of phases and noise")
    g.add_argument("--noise", type=float, default=5e-3, help="force-sensor noise std (N)")
    g.add_argument("--position-noise", type=float, default=0.0, help="encoder noise std (m)")
    g.add_argument(
        "--encoder-res", type=float, default=2e-6, help="encoder resolution (m), 0 = off"
    )


def _register_lab_frf_args(f):
    from ._cli_lab import register_lab_frf_args  # local: CLI start-up (hapid.io, equinox)

    register_lab_frf_args(f)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="hapid",
        description="Differentiable system identification and force control of multi-DOF "
        "haptic interfaces (Lee, Lawrence & Pao), on simulated devices or measured files.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    s = sub.add_parser("simulate", help="run the multisine experiments on a simulated device",
                       description="Run the paper's multisine experiments on a simulated device "
                       "and write a run file (.npz/.csv/.mat).",
                       epilog="example: hapid simulate --device cu5 --periods 8 --out run.npz")  # fmt: skip
    add_device_args(s, what=" to simulate")
    s.add_argument("--time-domain", action="store_true", help="lax.scan simulation instead of "
                   "the exact periodic steady state")  # fmt: skip
    s.add_argument("--friction", action="store_true", help="time domain with Coulomb friction")
    s.add_argument("--out", required=True, help="output run file")
    _protocol_args(s)
    s.set_defaults(func=cmd_simulate)

    f = sub.add_parser("frf", help="estimate Z_H, Z_T (and their std) from a run file",
                       description="Empirical impedances Z_H = −𝓡_I 𝓛⁻¹, Z_T = −𝓡_A 𝓛⁻¹ per "
                       "excited frequency (paper section 4.1), with element std.",
                       epilog="example: hapid frf run.npz --out frf.npz --plot frf.png")  # fmt: skip
    f.add_argument(
        "run", help="run file, or lab time series (fs_hz, force, response); .npz, .csv or .mat"
    )
    f.add_argument(
        "--out", required=True, help="output FRF file (an impedance FRF for a time series)"
    )
    f.add_argument("--plot", help="also write a figure of σ(Z_H), σ(Z_T), σ(P)")
    f.add_argument("--cond-warn", type=float, default=1e3, help="warn where cond(𝓛) exceeds this")
    _register_lab_frf_args(f)
    f.set_defaults(func=cmd_frf)

    d = sub.add_parser("demo", help="simulate the default device, estimate its FRF, plot σ",
                       epilog="example: hapid demo --out out/demo")  # fmt: skip
    add_device_args(d, what=" to simulate")
    d.add_argument("--out", default="out/demo")
    d.set_defaults(func=cmd_demo)

    for register in _EXTRA:
        register(sub)

    return annotate(p)  # missing help texts; every option's default in its help


def _register_scene(sub):
    p = sub.add_parser("paper", help="reproduce the paper's figures 5–10 and summary table",
                       description="Reproduce Lee, Lawrence & Pao's figures 5–10 on the simulated "
                       "cu5 with the paper's protocol, for the paper's WLS baseline and hapid's "
                       "NLS + PD fit, plus summary.md/summary.json (paper numbers next to ours).",
                       epilog="example: hapid paper --out out/paper")  # fmt: skip
    p.add_argument("--out", default="out/paper", help="output folder (default out/paper)")
    p.add_argument("--scene", help="use this scene file instead of the built-in paper scene")
    p.add_argument("--cache", default=".hapid_cache/stages", help="stage cache folder")
    p.add_argument("--no-cache", action="store_true", help="recompute every stage")
    p.set_defaults(func=cmd_paper)
    r = sub.add_parser("run", help="run a scene file (computes only what its outputs need)",
                       description="Run a scene (TOML): only the stages the requested outputs "
                       "need are computed, each cached on disk by a hash of its inputs.",
                       epilog="example: hapid run scenes/paper.toml --set controller.k=0.6")  # fmt: skip
    r.add_argument("scene", help="scene TOML file")
    r.add_argument("--out", help="output folder (default: the scene's outputs.dir)")
    r.add_argument("--outputs", help="comma list overriding outputs.want (e.g. fig6,summary)")
    r.add_argument("--set", action="append", metavar="SECTION.KEY=VALUE", help="override an option")
    r.add_argument("--cache", default=".hapid_cache/stages", help="stage cache folder")
    r.add_argument("--no-cache", action="store_true")
    r.set_defaults(func=cmd_run)


def _register_stages(sub):
    from ._cli_fit import register_fit  # local: CLI start-up (hapid.fit, optimistix)

    register_fit(sub, cmd_fit)

    an = sub.add_parser("analyze", help="closed-loop analysis: stability first, then bandwidth, margins",
                        description="Analyze the force loop of a model's controller on a simulated "
                        "device's true sampled plant or on a measured FRF: generalized Nyquist "
                        "verdict, isotropic bandwidth, gain/phase/disk margins, peak of T.",
                        epilog="example: hapid analyze --model model.npz --device cu5 --out report.json")  # fmt: skip
    an.add_argument("--model", required=True)
    src = an.add_mutually_exclusive_group(required=True)
    src.add_argument("--frf", help="measured FRF file whose P closes the loop")
    add_device_args(an, default=None, device_group=src, what=" whose true plant closes the loop")
    an.add_argument("--controller", choices=["mimo", "siso"], default="mimo")
    an.add_argument("--k", type=float, help="override the gain k of g(s) (paper: 0.85)")
    an.add_argument("--design", help="design file (.npz) from `hapid tune`: its tuned g closes the loop")  # fmt: skip
    an.add_argument("--continuous", action="store_true",
                    help="analyse the continuous-time controller with the continuous plant (as the "
                    "paper does; 0.005 Hz–5 kHz grid) instead of the sampled loop")  # fmt: skip
    an.add_argument("--siso-gain", type=float, help="SISO c (default: the 6 dB / 30° design rule)")
    an.add_argument("--fs", type=float, default=FS_HZ, help="sampling rate for --frf (Hz)")
    an.add_argument("--gm-db", type=float, default=None,
                    help="required GM (dB): print the verdict passed / failed / not established "
                    "first (default 6 when only --pm-deg is given)")  # fmt: skip
    an.add_argument("--pm-deg", type=float, default=None,
                    help="required PM (°), as --gm-db (default 30 when only --gm-db is given)")  # fmt: skip
    an.add_argument("--out", help="JSON report")
    an.set_defaults(func=cmd_analyze)

    po = sub.add_parser("posterior", help="emcee posterior (or Laplace) over M, B, K from an FRF",
                        epilog="example: hapid posterior frf.npz --out samples.npz --method laplace")  # fmt: skip
    po.add_argument("frf")
    po.add_argument("--out", required=True)
    po.add_argument("--model", help="(unused: the fit is redone, as hapid fit makes it)")
    po.add_argument("--method", choices=["emcee", "laplace"], default="emcee")
    po.add_argument("--walkers", type=int, default=0, help="0 = 2·dim + 2")
    po.add_argument(
        "--free-boundary",
        action="store_true",
        help="also sample matrices the NLS fit put on the PSD boundary (default: hold them)",
    )
    po.add_argument("--keep-boundary", action="store_true",
                    help="keep an NLS fit whose det Ẑ_H has a root at ∞ or on the imaginary axis "
                    "(default: refit it strictly PD, pd_eps = 1e-3, as hapid fit does)")  # fmt: skip
    po.add_argument(
        "--moves", default="de", help="emcee moves: de (default), laplace_de, de_mix, stretch"
    )
    po.add_argument("--steps", type=int, help="emcee steps (default: run to 50 τ)")
    po.add_argument("--samples", type=int, default=4000, help="Laplace draws")
    po.add_argument("--f-max-hz", type=float, default=FIT_BAND_HZ)
    po.add_argument("--max-steps", type=int, default=NLS_MAX_STEPS,
                    help=f"step limit of the NLS fit the posterior is built around (default: "
                    f"{NLS_MAX_STEPS}, as hapid fit)")  # fmt: skip
    po.add_argument("--model-error", choices=["white", "gp", "gp_corr", "none"], default="gp_corr",
                    help="model-error term: gp_corr (default: the misfit of Z_H and Z_M as correlated "
                         "smooth random functions of frequency, marginalized; its 90 %% band of P "
                         "covers held-out frequencies of misspecified devices, docs/conventions.md "
                         "'Posterior'), gp (independent hand/mechanism GPs), white (independent per "
                         "frequency: bands 2-6x too wide), none")  # fmt: skip
    po.add_argument("--gp-hyper", choices=["map", "marginal", "sample"], default=None,
                    help="gp hyperparameters: map (held at the joint posterior mode; gp default), "
                         "marginal (gp_corr only: mode of their marginal, M, B, K integrated out; gp_corr default) "
                         "or sample (sampled with M, B, K; ~100× slower per step)")  # fmt: skip
    po.add_argument("--error-scale", choices=["shared", "element"], default=None,
                    help="gp_corr model-error size per element: shared (one amplitude, the RMS "
                         "element size; default) or element (∝ each element's size in the fit; "
                         "docs/conventions.md)")  # fmt: skip
    po.add_argument("--seed", type=int, default=0)
    po.add_argument("--hdf5", help="emcee HDF5 backend file")
    po.set_defaults(func=cmd_posterior)

    ro = sub.add_parser("robust", help="robust-margin check of a nominal controller over samples",
                        epilog="example: hapid robust --samples samples.npz --model model.npz --device cu5 --out robust.json")  # fmt: skip
    ro.add_argument(
        "--samples",
        help="posterior samples file (hapid posterior; it also stores "
        "the measured FRF the loop draws need)",
    )
    ro.add_argument(
        "--frf",
        help="the measured FRF file (whole range): draws of the loop are "
        "conditioned on it (default: the FRF the samples file stores)",
    )
    ro.add_argument("--draws", default="auto", choices=list(DRAWS),
                    help="loop_gp: draws of Q = P P̂⁻¹ conditioned on the measured FRF "
                    "(calibrated where the model class is wrong); params: the samples' "
                    "second-order plants (parameter uncertainty only); auto (default): loop_gp "
                    "when a measured FRF is known")  # fmt: skip
    ro.add_argument("--model", required=True, action="append",
                    help="nominal model the controller is designed from; repeat to compare "
                    "controllers side by side (e.g. --model wls.npz --model nls.npz)")  # fmt: skip
    ro.add_argument("--controller", default="mimo", choices=["mimo"], help="controller kind")
    add_device_args(ro, default=None, what=" whose true plant is also checked (poses, subjects)")
    ro.add_argument("--subjects", type=int, default=0, help="virtual subjects for --device")
    ro.add_argument("--quiet", action="store_true", help="no progress on stderr")
    ro.add_argument("--gm-db", type=float, default=GM_DB)
    ro.add_argument("--pm-deg", type=float, default=PM_DEG)
    ro.add_argument("--fs", type=float, default=None,
                    help="rate (Hz) the controller runs at: the loop draws are checked with the "
                    "discretized controller (default: the device's with --device, else the "
                    "continuous-time controller)")  # fmt: skip
    ro.add_argument(
        "--max-samples",
        type=int,
        default=N_DRAWS,
        help="draws checked (posterior samples used, or loop draws made)",
    )
    ro.add_argument("--n-freq", type=int, default=None,
                    help="points of the analysis grid (default: 1000 for loop draws, 1500 for "
                    "parameter draws); denser resolves loci the default grid does not")  # fmt: skip
    ro.add_argument("--all-metrics", action="store_true",
                    help="also the disk margin and the peak of σ̄(T) (≈ 2× the time per plant)")  # fmt: skip
    ro.add_argument("--processes", type=int, default=None, help=_PROCESSES_HELP)
    ro.add_argument("--out", help="JSON report")
    ro.set_defaults(func=cmd_robust)


def _register_sweep(sub):
    sw = sub.add_parser("sweep", help="batched sweep over numeric scene options (one compiled vmap)",
                        description="Evaluate a scene's pipeline over the Cartesian product of "
                        "option values as one batched JAX computation: P·P̂⁻¹ band, stability "
                        "(the same verdict as hapid analyze), isotropic bandwidth, GM/PM, T peak "
                        "and disk margin per configuration.",
                        epilog="example: hapid sweep scenes/paper.toml --vary controller.k=0.4,0.6,0.85 "
                        "--vary protocol.noise=0.005,0.05 --out out/sweep")  # fmt: skip
    sw.add_argument("scene")
    sw.add_argument("--vary", action="append", required=True, metavar="KEY=V1,V2,…",
                    help="any numeric scene option: device.dx…droll, device.subject_seed, "
                    "device.delay_samples, device.rod_compliance, "
                    "protocol.noise/position_noise/periods/seed/amplitude, fit.* (NLS options "
                    "with --estimator nls), controller.k/lag_zero_hz/lag_pole_hz/zeta_num/"
                    "zeta_den/notch_hz[i]/lowpass_hz[i], analysis.f_min_hz/n_freq/band_hz")  # fmt: skip
    sw.add_argument("--estimator", default="wls+positize",
                    help="frf → model estimator: wls, wls+positize (default), nls")  # fmt: skip
    sw.add_argument("--chunk", type=int, default=64, help="configurations per compiled call")
    sw.add_argument("--processes", type=int, default=None, help=_PROCESSES_HELP)
    sw.add_argument("--out", default="out/sweep")
    sw.set_defaults(func=cmd_sweep)


def _register_tune(sub):
    tu = sub.add_parser("tune", help="tune g(s) by gradients, robustly over posterior samples / device variants",
                        description="Differentiable design of the compensator g(s) of G = g Ẑ_T Ẑ_H⁻¹: "
                        "maximize a smooth robust isotropic bandwidth subject to loci-sensitivity "
                        "constraints (GM ≥ 6 dB, PM ≥ 30°) on a CVaR quantile of posterior samples "
                        "(and, with --device, on the device's true plants at other poses and "
                        "subjects), then re-check paper g and tuned g with the non-smooth analysis "
                        "on held-out samples, the true plant and in the time domain. "
                        f"Expect about {TUNE_EXPECTED_S / 60:.0f} min with the defaults on a 2-core machine "
                        "(cu5, warm compilation cache; the first run compiles for longer); progress "
                        "(stage, BFGS steps, objective, worst constraint, elapsed / expected time) "
                        "goes to stderr, the report to stdout.",
                        epilog="example: hapid tune --model nls.npz --samples samples.npz --device cu5 --out design.npz")  # fmt: skip
    tu.add_argument("--model", required=True, help="nominal model file (the controller inverts it)")
    tu.add_argument("--samples", help="posterior samples file (hapid posterior)")
    add_device_args(tu, default=None,
                    what=": tune on its pose/subject variants, validate on its true plant")  # fmt: skip
    tu.add_argument("--frf", help="the measured FRF file (whole range): the evidence the design must hold on "
                    "(default: the measured FRF the samples file stores); beyond its top frequency the loop is kept small-gain")  # fmt: skip
    tu.add_argument("--fs", type=float, help="sampling rate (Hz) the controller runs at: the measured loop and "
                    "the small gain beyond it use the discretized controller (default: continuous)")  # fmt: skip
    tu.add_argument("--out", required=True, help="design file (.npz)")
    tu.add_argument("--report", help="JSON report of the re-check")
    tu.add_argument(
        "--n-train", type=int, default=TUNE_N_TRAIN, help="posterior samples used for tuning"
    )
    tu.add_argument(
        "--n-holdout",
        type=int,
        default=TUNE_N_HOLDOUT,
        help="held-out posterior samples for the re-check",
    )
    tu.add_argument(
        "--quantile",
        type=float,
        default=TUNE_QUANTILE,
        help="fraction of training samples that must meet the margins (chance constraint; "
        "held-out samples check it)",
    )
    tu.add_argument(
        "--subjects",
        type=int,
        default=TUNE_N_SUBJECTS,
        help="virtual subjects among the device variants",
    )
    tu.add_argument(
        "--max-steps", type=int, default=TUNE_MAX_STEPS, help="BFGS steps per continuation stage"
    )
    tu.add_argument("--free-dc", action="store_true",
                    help="let |g(0)| drop below the paper g's (trades static force accuracy for bandwidth)")  # fmt: skip
    tu.add_argument("--predictive", action="store_true",
                    help="tune and re-check on posterior-predictive plants (each draw plus its model-error "
                    "term, confined to the fit band) instead of the draws' second-order models")  # fmt: skip
    tu.add_argument("--evidence-bandwidth", action="store_true",
                    help="the measured FRF (--frf) claims the bandwidth, the draws keep the margins (chance "
                    "constraint); default: the median draw claims it")  # fmt: skip
    tu.add_argument("--draws", default="auto", choices=list(DRAWS),
                    help="what the design is tuned and re-checked on: loop_gp: draws of Q = P P̂⁻¹ "
                    "conditioned on the measured FRF (--frf, or the FRF the samples file stores; "
                    "calibrated where the model class is wrong: benchmarks/calibrate_robust.py); params: "
                    "the posterior samples' second-order plants; auto (default): loop_gp when a measured "
                    "FRF is known")  # fmt: skip
    tu.add_argument("--loop-draws", action="store_true", help="the same as --draws loop_gp")
    tu.add_argument("--extra-lag", type=float, nargs="+", metavar="HZ",
                    help="tune the paper g plus a lag/lead pair at each of these frequencies (Hz; zero = "
                    "pole at the start, so the start is the paper g): more freedom in g's shape")  # fmt: skip
    tu.add_argument("--extra-notch", type=float, nargs="+", metavar="HZ",
                    help="tune the paper g plus a notch (ζ_num = ζ_den at the start) at each of these "
                    "frequencies (Hz): it can become a dip or a bump")  # fmt: skip
    tu.add_argument("--seed", type=int, default=0)
    tu.add_argument("--quiet", action="store_true", help="no progress on stderr")
    tu.set_defaults(func=cmd_tune)


def _register_predict(sub):
    from ._cli_predict import register  # local: CLI start-up (hapid.io, equinox)

    register(sub)


def _parse_command(argv: list[str]) -> argparse.Namespace:
    """A ``hapid`` command line parsed by the real parser (every option's default)."""
    return build_parser().parse_args(argv)


def _register_design(sub):
    from ._cli_design import register  # local: CLI start-up (hapid.io, equinox)

    register(sub, _parse_command)


_EXTRA: list = [
    _register_scene,
    _register_stages,
    _register_sweep,
    _register_tune,
    _register_predict,
    _register_design,
]  # later stages register their subcommands here


def _one_line_errors(parser) -> None:
    """argparse's own errors (bad type, bad choice, missing option, unknown subcommand) as one
    ``hapid: error:`` line with a hint, instead of the usage dump."""

    def error(p, message):
        cmd = p.prog.removeprefix("hapid").strip()
        hint = f"hapid {cmd} -h lists its options" if cmd else "hapid -h lists the commands"
        print(f"hapid: error: {cmd + ': ' if cmd else ''}{message} ({hint})", file=sys.stderr)
        sys.exit(2)

    parser.error = error.__get__(parser)
    for act in parser._actions:
        for sub in (getattr(act, "choices", None) or {}).values():
            if isinstance(sub, argparse.ArgumentParser):
                sub.error = error.__get__(sub)


def main(argv=None) -> int:
    parser = build_parser()
    _one_line_errors(parser)
    a = parser.parse_args(argv)
    if not getattr(a, "command", None):
        parser.print_help()
        return 0
    warnings.simplefilter("default")
    warnings.formatwarning = lambda m, c, *_: f"hapid: warning: {m}\n"
    try:
        from ._cli_checks import check_args  # local: CLI start-up (hapid.io, equinox)

        check_args(parser, a)  # every option and scene key, before any work
        if hasattr(a, "processes"):  # sweep, robust: hapid._distributed (HAPID_* or --processes)
            if a.processes is not None and _distributed.local_launch_needed(a.processes):
                args = sys.argv[1:] if argv is None else list(argv)
                return _distributed.launch_local(args, a.processes)
            _distributed.initialize()
        a.func(a)
    except (ValueError, FileNotFoundError, CLIError, OSError) as e:
        if os.environ.get("HAPID_DEBUG"):
            raise
        print(f"hapid: error: {e}", file=sys.stderr)
        return 2
    except Exception as e:  # a bug: still one line (HAPID_DEBUG=1 for the traceback)
        if os.environ.get("HAPID_DEBUG"):
            raise
        print(f"hapid: internal error ({type(e).__name__}, please report; HAPID_DEBUG=1 shows "
              f"the traceback): {e}", file=sys.stderr)  # fmt: skip
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
