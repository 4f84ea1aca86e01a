"""The option table of the command line: the rule of every option of every subcommand.

``COMMON`` holds the options that mean the same in every subcommand that has them;
``PER_COMMAND[command]`` the files and the options whose meaning depends on the command (it
wins over ``COMMON``). ``rule_for(command, dest)`` returns the rule (``KeyError`` if neither
table has one). Rules are built by ``hapid._cli_checks_rules``.
"""

from __future__ import annotations

import math

from ._cli_checks_rules import (
    ANY,
    FLAG,
    MOVE_LIMIT_M,
    SEED,
    _In,
    _int,
    _num,
    _Out,
    _presets,
    between,
    ge,
    gt,
    int_between,
    int_ge,
    one_of,
)
from ._cli_device import PRESETS_TEXT
from .defaults import DRAWS

#: largest --n-freq of predict/plant: their files hold S draws × N frequencies × n × n
N_FREQ_DRAWS_MAX = 100_000

RUN_EXT = (".npz", ".csv", ".mat")
ARRAY_EXT = (".npz", ".mat")
FIG_EXT = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


# ---- the option table -----------------------------------------------------------------------
def _freqs(v):
    if v == "paper":
        return True
    try:
        f = [float(x) for x in str(v).split(",")]
    except ValueError:
        return False
    return len(f) > 0 and all(math.isfinite(x) and x > 0 for x in f)


def _move(v):
    return (isinstance(v, list | tuple) and len(v) == 3 and all(_num(x) for x in v)
            and all(abs(x) <= MOVE_LIMIT_M for x in v))  # fmt: skip


def _pos_list(v):
    return isinstance(v, list | tuple) and len(v) > 0 and all(_num(x) and x > 0 for x in v)


def _walkers(v):
    return _int(v) and (v == 0 or 2 <= v <= 100_000)


# options that mean the same thing in every subcommand that has them
COMMON: dict[str, tuple] = {
    "device": (lambda v: v in _presets(), f"a preset device ({PRESETS_TEXT})"),
    "rod_compliance": between(1e-3, 1e3),  # the --device options: hapid._cli_device
    "fs": gt(0, " Hz"),
    "freqs": (_freqs, "'paper' or a comma list of frequencies > 0 Hz (e.g. 1,2,5)"),
    "period": int_between(2, 10**6),
    "periods": int_between(1, 10**4),
    "transient": int_between(0, 10**6),
    "pattern": one_of(["paper", "one_at_a_time", "hadamard"]),
    "phases": one_of(["random", "schroeder", "min_crest"]),
    "amplitude": gt(0, " N"),
    "seed": SEED,
    "noise": ge(0, " N"),
    "position_noise": ge(0, " m"),
    "encoder_res": ge(0, " m (0 = off)"),
    "move": (_move, f"three finite displacements within ±{MOVE_LIMIT_M:g} m of home"),
    "time_domain": FLAG,
    "friction": FLAG,
    "cond_warn": ge(1),
    "method": ANY,  # choices: argparse checks them
    "positize": FLAG,
    "weight": ANY,
    "solver": (
        lambda v: v in _solvers(),
        "one of lm, dogleg, gauss_newton, bfgs, nonlinear_cg, jaxopt_lm",
    ),
    "f_max_hz": gt(0, " Hz"),
    "f_min_hz": ge(0, " Hz"),
    "h1": FLAG,
    "nperseg": int_between(8, 10**8),
    "response": one_of(["displacement", "velocity", "acceleration"]),
    "sign": one_of(["+", "-"]),
    "window": one_of(["hann", "boxcar"]),
    "estimate": one_of(["auto", "impact", "welch"]),
    "force_window": gt(0, " s"),
    "exp_tau": gt(0, " s"),
    "fs_hz": gt(0, " Hz"),
    "force_key": ANY,
    "response_key": ANY,
    "force_unit": ANY,
    "length_unit": ANY,
    "continuous": FLAG,
    "model_floor": ge(0),
    "true_device": (lambda v: v in _presets(), f"a preset device ({PRESETS_TEXT})"),
    "model_error": one_of(["white", "gp", "gp_corr", "none"]),
    "gp_hyper": one_of(["map", "marginal", "sample"]),
    "error_scale": one_of(["shared", "element"]),
    "n_freq": int_between(2, 1_000_000),
    "no_model_error": FLAG,
    "delay": int_between(0, 1000),
    "omega_c_hz": gt(0, " Hz"),
    "max_steps": int_between(1, 10**6),
    "band_hz": gt(0, " Hz"),
    "allow_unconverged": FLAG,
    "keep_boundary": FLAG,
    "controller": ANY,
    "k": gt(0),
    "siso_gain": gt(0),
    "walkers": (_walkers, "0 (= 2·dim + 2) or an integer in [2·dim, 100000]"),
    "free_boundary": FLAG,
    "moves": one_of(["de", "laplace_de", "de_mix", "stretch"]),
    "steps": int_between(1, 10**7),
    "subjects": int_between(0, 10_000),
    "gm_db": between(0, 60, " dB"),
    "pm_deg": between(0, 180, "°", hi_open=True),
    "max_samples": int_between(1, 10**7),
    "all_metrics": FLAG,  # robust: also the disk margin and T peak
    "chunk": int_between(1, 10**5),
    "processes": int_between(1, 4096),  # sweep, robust: local jax.distributed processes
    "n_train": int_between(1, 10**6),
    "n_holdout": int_between(1, 10**6),
    "quantile": between(0, 1, lo_open=True),
    "free_dc": FLAG,
    "predictive": FLAG,
    "evidence_bandwidth": FLAG,
    "loop_draws": FLAG,
    "draws": one_of(list(DRAWS)),
    "extra_lag": (_pos_list, "one or more frequencies > 0 Hz"),
    "extra_notch": (_pos_list, "one or more frequencies > 0 Hz"),
    "no_cache": FLAG,
    "outputs": ANY,  # checked with the scene (run)
    "set": ANY,  # checked with the scene (run)
    "vary": ANY,  # checked with the scene (sweep)
    "cache": _Out("a cache folder"),
}

# per-subcommand rules (files, and options whose meaning depends on the command)
PER_COMMAND: dict[str, dict] = {
    "simulate": {"out": _Out("a run file", RUN_EXT)},
    "frf": {"run": _In("a run file", RUN_EXT), "out": _Out("an FRF file", RUN_EXT),
            "plot": _Out("a figure file", FIG_EXT), "add": _In("a record file", RUN_EXT)},
    "demo": {"out": _Out("an output folder")},
    "fit": {"frf": _In("an FRF file", RUN_EXT), "out": _Out("a model file", ARRAY_EXT)},
    "analyze": {"model": _In("a model file", ARRAY_EXT), "frf": _In("an FRF file", RUN_EXT),
                "out": _Out("a JSON report", (".json",)),
                "design": _In("a design file from hapid tune", (".npz",))},
    "posterior": {"frf": _In("an FRF file", RUN_EXT), "out": _Out("a samples file", (".npz",)),
                  "model": _In("a model file", ARRAY_EXT), "samples": int_between(1, 10**7),
                  "model_error": one_of(["white", "gp", "gp_corr", "none"]),
                  "hdf5": _Out("an emcee HDF5 backend file", (".h5", ".hdf5"))},
    "robust": {"samples": _In("a posterior-samples file", (".npz",)), "frf": _In("an FRF file", RUN_EXT),
               "model": _In("a model file", ARRAY_EXT), "out": _Out("a JSON report", (".json",)),
               "quiet": FLAG},
    "sweep": {"scene": _In("a scene TOML", (".toml",)), "out": _Out("an output folder"),
              "estimator": ((lambda v: v in _estimators()),
                            "a registered estimator (hapid.pipeline.ESTIMATORS: wls, wls+positize, nls, …)")},
    "tune": {"model": _In("a model file", ARRAY_EXT),
             "samples": _In("a posterior-samples file", (".npz",)), "frf": _In("an FRF file", RUN_EXT),
             "out": _Out("a design file", (".npz",)), "report": _Out("a JSON report", (".json",)),
             "quiet": FLAG},
    "paper": {"out": _Out("an output folder"), "scene": _In("a scene TOML", (".toml",))},
    "predict": {"samples": _In("a posterior-samples file", (".npz",)), "out": _Out("a draws file", (".npz",)),
                "f_min_hz": gt(0, " Hz"), "n_freq": int_between(2, N_FREQ_DRAWS_MAX), "no_model_error": FLAG,
                "no_check": FLAG, "no_recalibrate": FLAG, "plot": _Out("a figure file", FIG_EXT)},
    "plant": {"out": _Out("an FRF file", (".npz",)), "n_freq": int_between(2, N_FREQ_DRAWS_MAX),
              "f_min_hz": gt(0, " Hz")},
    "run": {"scene": _In("a scene TOML", (".toml",)), "out": _Out("an output folder")},
    "design": {"input": _In("a run, FRF or time-series file", RUN_EXT), "out": _Out("an output folder"),
               "samples": int_ge(1), "posterior": one_of(["laplace", "emcee"]),
               "skip": ANY, "only": ANY,  # argparse choices: the stage names
               "lab_f_min_hz": gt(0, " Hz"), "lab_f_max_hz": gt(0, " Hz")},
}  # fmt: skip


def _estimators():
    from .pipeline import ESTIMATORS  # local: CLI start-up (hapid.fit, optimistix)

    return ESTIMATORS


def _solvers():
    from .fit import SOLVERS  # local: CLI start-up (hapid.fit, optimistix)

    return SOLVERS


def rule_for(command: str, dest: str):
    """The rule of option ``dest`` of ``command`` (``KeyError`` if the table has none)."""
    return PER_COMMAND.get(command, {}).get(dest) or COMMON[dest]
