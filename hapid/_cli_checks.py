"""The ONE table of command-line checks, applied by ``hapid.cli.main`` after parsing and before
any work: every option of every subcommand has a rule here (a test enforces it), and a value out
of range is one line naming the option, the value and what is allowed, e.g.
``--fs must be > 0 Hz, got 0``. Scene files (``run``, ``sweep``, ``paper --scene``) are checked
key by key with the same rules (``check_scene``).

A rule is ``(test, allowed)``: ``test(value) -> bool`` and ``allowed`` the text after
"must be". ``None`` values (an option not given) are never checked.
"""

from __future__ import annotations

import math
from pathlib import Path

from ._cli_checks_io import check_model_matches_device, check_out_not_input
from ._cli_device import PRESETS_TEXT, variant_flags
from .defaults import DRAWS

# ---- value tests ----------------------------------------------------------------------------


def _num(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def gt(lo, unit=""):
    return (lambda v: _num(v) and v > lo), f"> {lo:g}{unit}"


def ge(lo, unit=""):
    return (lambda v: _num(v) and v >= lo), f"≥ {lo:g}{unit}"


def between(lo, hi, unit="", lo_open=False, hi_open=False):
    def test(v):
        return _num(v) and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)

    a, b = "(" if lo_open else "[", ")" if hi_open else "]"
    u = unit.strip()
    sep = "" if u in ("°", "") else " "
    return test, f"in {a}{lo:g}{sep}{u}, {hi:g}{sep}{u}{b}"


def int_ge(lo):
    return (lambda v: _int(v) and v >= lo), f"an integer ≥ {lo}"


def int_between(lo, hi):
    return (lambda v: _int(v) and lo <= v <= hi), f"an integer in [{lo}, {hi}]"


def one_of(choices):
    choices = tuple(choices)
    return (lambda v: v in choices), f"one of {', '.join(map(str, choices))}"


ANY = (lambda v: True), "anything"
FLAG = (lambda v: isinstance(v, bool)), "true or false"
SEED = int_between(0, 2**32 - 1)
MOVE_LIMIT_M = 0.2  # the base hexagon's radius: the stylus stays inside the rods' reach
ROT_LIMIT_RAD = 0.5

#: no numeric option is larger in size than this (a value such as 1e300 is a typo, and would
#: overflow the simulation or the fit)
MAGNITUDE_MAX = 1e12
#: largest --n-freq of predict/plant: their files hold S draws × N frequencies × n × n
N_FREQ_DRAWS_MAX = 100_000

RUN_EXT = (".npz", ".csv", ".mat")
ARRAY_EXT = (".npz", ".mat")
FIG_EXT = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def _presets():
    from .device._presets import PRESETS

    return tuple(sorted(PRESETS))


def _nyquist_hz(preset: str = "cu5") -> float:
    import inspect

    from .device._presets import PRESETS

    return 0.5 * float(inspect.signature(PRESETS[preset]).parameters["fs_hz"].default)


# ---- files ----------------------------------------------------------------------------------
class _In:
    """An input file: must exist, be a file, and have one of ``ext`` (None = any)."""

    def __init__(self, what, ext=None):
        self.what, self.ext = what, ext


class _Out:
    """An output file (``ext``) or folder (``ext`` None): its place must be writable."""

    def __init__(self, what, ext=None):
        self.what, self.ext = what, ext


def _check_in(opt, path, rule: _In):
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{opt}: {p}: no such file (expected {rule.what})")
    if p.is_dir():
        raise ValueError(f"{opt}: {p} is a folder; expected {rule.what}")
    if rule.ext and p.suffix.lower() not in rule.ext:
        raise ValueError(
            f"{opt}: {p} has suffix {p.suffix or '(none)'!r}; expected {rule.what} "
            f"({', '.join(rule.ext)})"
        )


def _check_out(opt, path, rule: _Out):
    p = Path(path)
    if str(path).strip() == "":
        raise ValueError(f"{opt} must be a path, got an empty string")
    if rule.ext is None:
        if p.exists() and not p.is_dir():
            raise ValueError(f"{opt}: {p} is a file; expected {rule.what}")
    else:
        if p.is_dir():
            raise ValueError(f"{opt}: {p} is a folder; expected {rule.what}")
        if p.suffix.lower() not in rule.ext:
            raise ValueError(
                f"{opt}: {p} has suffix {p.suffix or '(none)'!r}; expected {rule.what} "
                f"({', '.join(rule.ext)})"
            )
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{opt}: cannot write {p}: {parent} is a file, not a folder")
            break


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
               "model": _In("a model file", ARRAY_EXT), "out": _Out("a JSON report", (".json",))},
    "sweep": {"scene": _In("a scene TOML", (".toml",)), "out": _Out("an output folder"),
              "estimator": ((lambda v: v in _estimators()),
                            "a registered estimator (hapid.pipeline.ESTIMATORS: wls, wls+positize, nls, …)")},
    "tune": {"model": _In("a model file", ARRAY_EXT),
             "samples": _In("a posterior-samples file", (".npz",)), "frf": _In("an FRF file", RUN_EXT),
             "out": _Out("a design file", (".npz",)), "report": _Out("a JSON report", (".json",)),
             "quiet": FLAG},
    "paper": {"out": _Out("an output folder"), "scene": _In("a scene TOML", (".toml",))},
    "predict": {"samples": _In("a posterior-samples file", (".npz",)), "out": _Out("a draws file", (".npz",)),
                "f_min_hz": gt(0, " Hz"), "n_freq": int_between(2, N_FREQ_DRAWS_MAX), "no_model_error": FLAG},
    "plant": {"out": _Out("an FRF file", (".npz",)), "n_freq": int_between(2, N_FREQ_DRAWS_MAX),
              "f_min_hz": gt(0, " Hz")},
    "run": {"scene": _In("a scene TOML", (".toml",)), "out": _Out("an output folder")},
    "design": {"input": _In("a run, FRF or time-series file", RUN_EXT), "out": _Out("an output folder"),
               "samples": int_ge(1), "posterior": one_of(["laplace", "emcee"]),
               "skip": ANY, "only": ANY,  # argparse choices: the stage names
               "lab_f_min_hz": gt(0, " Hz"), "lab_f_max_hz": gt(0, " Hz")},
}  # fmt: skip


def _estimators():
    from .pipeline import ESTIMATORS

    return ESTIMATORS


def _solvers():
    from .fit import SOLVERS

    return SOLVERS


def rule_for(command: str, dest: str):
    """The rule of option ``dest`` of ``command`` (``KeyError`` if the table has none)."""
    return PER_COMMAND.get(command, {}).get(dest) or COMMON[dest]


def _show(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, list | tuple):
        return " ".join(_show(x) for x in v)
    return str(v)


def check_option(command: str, opt: str, dest: str, value) -> None:
    """Raise ``ValueError`` if ``value`` breaks the rule of ``dest`` (``opt``: its flag)."""
    if value is None:
        return
    rule = rule_for(command, dest)
    if isinstance(rule, _In):
        for v in value if isinstance(value, list) else [value]:
            _check_in(opt, v, rule)
        return
    if isinstance(rule, _Out):
        _check_out(opt, value, rule)
        return
    test, allowed = rule
    if not test(value):
        raise ValueError(f"{opt} must be {allowed}, got {_show(value)}")
    for v in value if isinstance(value, list | tuple) else [value]:
        if _num(v) and abs(v) > MAGNITUDE_MAX:
            raise ValueError(
                f"{opt} must be at most {MAGNITUDE_MAX:g} in size (no physical value is larger), "
                f"got {_show(value)}"
            )


def options(parser, command: str):
    """``[(dest, flag)]`` of every option and positional of ``command``'s subparser."""
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    out = []
    for act in sub._actions:
        if act.dest == "help":
            continue
        flag = max(act.option_strings, key=len) if act.option_strings else act.dest
        out.append((act.dest, flag))
    return out


def check_args(parser, a) -> None:
    """Check every option of the parsed command ``a`` (then scene files and cross-option
    rules); raise ``ValueError`` naming the first problem. Does no work beyond reading small
    text files (scenes)."""
    cmd = a.command
    outs, ins = {}, {}
    for dest, flag in options(parser, cmd):
        check_option(cmd, flag, dest, getattr(a, dest, None))
        rule = PER_COMMAND.get(cmd, {}).get(dest) or COMMON.get(dest)
        if isinstance(rule, _Out) and rule.ext is not None:
            outs[flag] = getattr(a, dest, None)
        elif isinstance(rule, _In):
            ins[flag] = getattr(a, dest, None)
    check_out_not_input(outs, ins)
    extra = _CROSS.get(cmd)
    if extra is not None:
        extra(a)


# ---- cross-option rules ---------------------------------------------------------------------
def _protocol_cross(a):
    from .experiment._excitation import check_on_grid, paper_frequencies

    f = paper_frequencies() if a.freqs == "paper" else [float(x) for x in a.freqs.split(",")]
    try:
        check_on_grid(f, a.fs, a.period)
    except ValueError as e:
        raise ValueError(f"--freqs/--fs/--period: {e}") from None


def _band_cross(a):
    lo, hi = getattr(a, "f_min_hz", None), getattr(a, "f_max_hz", None)
    if lo is not None and hi is not None and lo >= hi:
        raise ValueError(f"--f-min-hz ({lo:g}) must be < --f-max-hz ({hi:g})")


def _device_cross(a):
    """``--delay``, ``--rod-compliance``, ``--move`` vary the ``--device`` preset: not without it."""
    given = variant_flags(a)
    if given and a.device is None:
        raise ValueError(f"{', '.join(given)}: a variant of the --device preset; give --device too")


def _analyze_cross(a):
    _device_cross(a)
    if getattr(a, "design", None) is not None and a.k is not None:
        raise ValueError("--k and --design are exclusive (the design file holds its own gain)")
    if a.frf is None and a.fs != 1000.0:
        raise ValueError(
            f"--fs is for --frf only (the --device preset has its own rate), got {a.fs:g}"
        )


def _tune_cross(a):
    _device_cross(a)
    loop = getattr(a, "loop_draws", False) or getattr(a, "draws", "auto") == "loop_gp"
    if loop and a.frf is None and a.samples is None:
        raise ValueError("hapid tune --draws loop_gp needs the measured FRF (--frf, or --samples "
                         "from hapid posterior, which stores it)")  # fmt: skip
    if getattr(a, "draws", "auto") == "params" and a.samples is None:
        raise ValueError("hapid tune --draws params needs --samples")
    if a.samples is None and a.device is None and a.frf is None:
        raise ValueError("hapid tune needs --samples, --frf, --device, or a combination")


def _robust_cross(a):
    _device_cross(a)
    if a.samples is None and a.frf is None:
        raise ValueError("give --samples (hapid posterior) or --frf (the measured FRF), or both")
    if a.draws == "params" and a.samples is None:
        raise ValueError("--draws params checks the samples' own plants: give --samples")
    if len(a.model) > 1 and a.out is not None and Path(a.out).suffix.lower() != ".json":
        raise ValueError(f"--out must be a .json file, got {a.out}")
    check_model_matches_device(a.model, a.device)


def _run_cross(a):
    from . import scene as _scene

    cfg = load_scene_checked(a.scene)
    for kv in a.set or []:
        key, eq, val = kv.partition("=")
        if not eq:
            raise ValueError(f"--set needs SECTION.KEY=VALUE, got {kv!r}")
        try:
            cfg = _scene.set_option(cfg, key, _parse_value(val))
        except ValueError as e:
            raise ValueError(f"--set {kv}: {e}") from None
    if a.outputs is not None:
        bad = [o for o in a.outputs.split(",") if o not in _scene.OUTPUTS]
        if bad:
            raise ValueError(
                f"--outputs must be a comma list of {', '.join(_scene.OUTPUTS)}, got {a.outputs}"
            )
    check_scene(cfg, "--set" if a.set else str(a.scene))


def _paper_cross(a):
    if a.scene is not None:
        check_scene(load_scene_checked(a.scene), str(a.scene))


SWEEP_KEYS = {
    "fit.omega_c_hz": gt(0, " Hz"), "protocol.noise": ge(0, " N"),
    "protocol.position_noise": ge(0, " m"), "protocol.periods": int_ge(1),
    "protocol.seed": SEED, "controller.k": gt(0), "device.subject_seed": SEED,
    "device.dx": between(-MOVE_LIMIT_M, MOVE_LIMIT_M, " m"),
    "device.dy": between(-MOVE_LIMIT_M, MOVE_LIMIT_M, " m"),
    "device.dz": between(-MOVE_LIMIT_M, MOVE_LIMIT_M, " m"),
}  # fmt: skip


def _as_int_if_whole(x: float):
    return int(x) if math.isfinite(x) and x == int(x) else x


def _sweep_cross(a):
    check_scene(load_scene_checked(a.scene), str(a.scene))
    seen = set()
    for item in a.vary:
        key, eq, vals = item.partition("=")
        if not eq or not vals:
            raise ValueError(f"--vary needs KEY=V1,V2,…; got {item!r}")
        if key in seen:
            raise ValueError(f"--vary {key} given twice")
        seen.add(key)
        if key not in SWEEP_KEYS:  # any other numeric option: the sweep's own rules (hapid.sweep)
            from . import sweep as _sweep

            try:
                _sweep.classify(
                    key, load_scene_checked(a.scene), getattr(a, "estimator", "wls+positize")
                )
            except ValueError as e:
                raise ValueError(f"--vary: {e}") from None
            cfg = load_scene_checked(a.scene)
            for s in vals.split(","):
                try:
                    x = float(s)
                except ValueError:
                    raise ValueError(f"--vary {key}: {s!r} is not a number") from None
                _check_swept_value(cfg, key, s, x)
            continue
        test, allowed = SWEEP_KEYS[key]
        for s in vals.split(","):
            try:
                x = float(s)
            except ValueError:
                raise ValueError(f"--vary {key}: {s!r} is not a number") from None
            xv = _as_int_if_whole(x) if allowed.startswith("an integer") else x
            if not test(xv):
                raise ValueError(f"--vary {key} must be {allowed}, got {s}")


def _check_swept_value(cfg: dict, key: str, text: str, x: float) -> None:
    """A swept value of any scene option obeys that option's scene rule (an integer option
    takes whole numbers only)."""
    import copy

    from . import sweep as _sweep

    sec, k, i = _sweep._parse(key)
    cur = cfg[sec][k] if i is None else None
    if _int(cur) or key in _sweep._INTEGER:
        if not (math.isfinite(x) and x == int(x)):
            raise ValueError(f"--vary {key} must be an integer, got {text}")
        x = int(x)
    c = copy.deepcopy(cfg)
    _sweep._set(c, key, x)
    check_scene(c, f"--vary {key}={text}")


_CROSS = {"simulate": _protocol_cross, "analyze": _analyze_cross, "tune": _tune_cross,
          "robust": _robust_cross, "run": _run_cross, "paper": _paper_cross,
          "sweep": _sweep_cross, "fit": _band_cross, "frf": _band_cross,
          "predict": _band_cross, "plant": _band_cross}  # fmt: skip


def _parse_value(val: str):
    import json

    try:
        return json.loads(val)
    except json.JSONDecodeError:
        return val


# ---- scene files ----------------------------------------------------------------------------
def load_scene_checked(path) -> dict:
    """Read a scene TOML (merged over the defaults), with a clear error for anything else."""
    import tomllib

    from . import scene as _scene

    p = Path(path)
    raw = p.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(
            f"{p}: binary data, not text; expected a scene TOML (e.g. scenes/paper.toml)"
        ) from None
    try:
        user = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{p}: invalid TOML ({e}); expected a scene TOML") from None
    return _scene.merge(user, source=str(p))


def _list_of(test_one, allowed_one, min_len=1, max_len=None):
    def test(v):
        return (isinstance(v, list) and min_len <= len(v) <= (max_len or len(v))
                and all(test_one(x) for x in v))  # fmt: skip

    return (
        test,
        f"a list of {min_len}{'–' + str(max_len) if max_len else '+'} numbers {allowed_one}",
    )


def _scene_move(v):
    if not (isinstance(v, list) and len(v) <= 6 and all(_num(x) for x in v)):
        return False
    return all(abs(x) <= MOVE_LIMIT_M for x in v[:3]) and all(
        abs(x) <= ROT_LIMIT_RAD for x in v[3:]
    )


def _scene_freqs(v):
    return v == "paper" or (
        isinstance(v, list) and len(v) > 0 and all(_num(x) and x > 0 for x in v)
    )


def _scene_rules() -> dict:
    nyq = _nyquist_hz()
    pos = lambda x: _num(x) and 0 < x < nyq  # noqa: E731
    from .scene import OUTPUTS

    return {
        "device.preset": (lambda v: v in _presets(), f"one of {', '.join(_presets())}"),
        "device.move": (_scene_move, f"a list of ≤ 6 numbers: dx dy dz within ±{MOVE_LIMIT_M:g} m, "
                        f"dyaw dpitch droll within ±{ROT_LIMIT_RAD:g} rad"),
        "device.subject_seed": (lambda v: v is None or SEED[0](v), "an integer in [0, 2^32 - 1]"),
        "device.light_damping": FLAG, "device.extra_modes": FLAG,
        "device.encoder": one_of(["motor", "rod"]),
        "device.delay_samples": (lambda v: v is None or COMMON["delay"][0](v),
                                 "an integer in [0, 1000] (samples; unset: the preset's)"),
        "device.rod_compliance": (lambda v: v is None or COMMON["rod_compliance"][0](v),
                                  "a number in [0.001, 1000] (unset: the preset's)"),
        "protocol.freqs": (_scene_freqs, "'paper' or a non-empty list of frequencies > 0 Hz"),
        "protocol.periods": int_ge(1), "protocol.transient": int_ge(0),
        "protocol.pattern": COMMON["pattern"], "protocol.phases": COMMON["phases"],
        "protocol.amplitude": gt(0, " N"), "protocol.seed": SEED, "protocol.noise": ge(0, " N"),
        "protocol.position_noise": ge(0, " m"), "protocol.encoder_res": ge(0, " m"),
        "protocol.synthesis": one_of(["periodic", "time_domain"]), "protocol.friction": FLAG,
        "fit.omega_c_hz": gt(0, " Hz"), "fit.positize": FLAG, "fit.boundary_refit": FLAG,
        "fit.weight": one_of(["relative", "paper", "noise", "blend"]),
        "fit.f_max_hz": gt(0, " Hz"),
        "fit.max_steps": int_ge(1), "fit.rtol": gt(0), "fit.atol": gt(0), "fit.ftol": gt(0),
        "fit.patience": int_ge(1), "fit.blend_floor": gt(0), "fit.p_weight": ge(0),
        "fit.pd_eps": ge(0), "fit.init_floor": ge(0),
        "fit.solver": (lambda v: v in _solvers(), f"one of {', '.join(_solvers())}"),
        "controller.k": gt(0), "controller.lag_zero_hz": between(0, nyq, " Hz", True, True),
        "controller.lag_pole_hz": between(0, nyq, " Hz", True, True),
        "controller.notch_hz": _list_of(pos, f"in (0, {nyq:g}) Hz", 0),
        "controller.zeta_num": ge(0), "controller.zeta_den": gt(0),
        "controller.lowpass_hz": _list_of(pos, f"in (0, {nyq:g}) Hz", 0),
        "controller.siso_gm_db": between(0, 60, " dB", lo_open=True),
        "controller.siso_pm_deg": between(0, 180, "°", True, True),
        "analysis.f_min_hz": between(0, nyq, " Hz", True, True),
        "analysis.n_freq": int_between(16, 1_000_000), "analysis.band_hz": gt(0, " Hz"),
        "posterior.walkers": (_walkers, "0 (= 2·dim + 2) or an integer in [2, 100000]"),
        "posterior.steps": int_ge(1), "posterior.seed": SEED, "posterior.samples": int_ge(1),
        "outputs.want": (lambda v: isinstance(v, list) and all(x in OUTPUTS for x in v),
                         f"a list of {', '.join(OUTPUTS)}"),
        "outputs.dir": (lambda v: isinstance(v, str) and v.strip() != "", "a folder path"),
    }  # fmt: skip


def _by_type(v):
    """Rule for a scene key without its own entry (options a stage grew since): numbers must
    be finite, flags booleans; anything else is left to the stage."""
    if isinstance(v, bool):
        return FLAG
    if isinstance(v, int | float):
        return (_num, "a finite number")
    return ANY


def check_scene(cfg: dict, source: str) -> None:
    """Raise ``ValueError`` naming the first scene key (``section.key``) whose value is out of
    range, its value and what is allowed (``source``: the file or option it came from)."""
    rules = _scene_rules()
    for sec, vals in cfg.items():
        for k, v in vals.items():
            key = f"{sec}.{k}"
            test, allowed = rules.get(key) or _by_type(v)
            if not test(v):
                raise ValueError(f"{source}: {key} must be {allowed}, got {v!r}")
    from .experiment._excitation import check_on_grid, paper_frequencies

    fr = cfg["protocol"]["freqs"]
    try:
        check_on_grid(
            paper_frequencies() if fr == "paper" else fr,
            2 * _nyquist_hz(cfg["device"]["preset"]),
            1000,
        )
    except ValueError as e:
        raise ValueError(f"{source}: protocol.freqs: {e}") from None
