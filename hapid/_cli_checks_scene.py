"""The checks of scene files (``hapid run``, ``hapid sweep``, ``hapid paper --scene``): one
rule per scene key (``section.key``), the same rules as the matching command-line options.

``load_scene_checked(path) -> dict`` reads a scene TOML merged over the defaults;
``check_scene(cfg, source)`` raises ``ValueError`` naming the first key out of range, its value
and what is allowed. A key without its own rule is checked by type (numbers finite, flags
booleans).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from . import scene as _scene
from ._cli_checks_rules import (
    ANY,
    FLAG,
    MOVE_LIMIT_M,
    ROT_LIMIT_RAD,
    SEED,
    _num,
    _nyquist_hz,
    _presets,
    between,
    ge,
    gt,
    int_between,
    int_ge,
    one_of,
)
from ._cli_checks_table import COMMON, _solvers, _walkers
from .experiment._excitation import check_on_grid, paper_frequencies
from .scene import OUTPUTS


# ---- scene files ----------------------------------------------------------------------------
def load_scene_checked(path) -> dict:
    """Read a scene TOML (merged over the defaults), with a clear error for anything else."""
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

    fr = cfg["protocol"]["freqs"]
    try:
        check_on_grid(
            paper_frequencies() if fr == "paper" else fr,
            2 * _nyquist_hz(cfg["device"]["preset"]),
            1000,
        )
    except ValueError as e:
        raise ValueError(f"{source}: protocol.freqs: {e}") from None
