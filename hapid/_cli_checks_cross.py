"""The cross-option checks of the command line: rules that involve more than one option of a
subcommand (``--f-min-hz < --f-max-hz``, device variants need ``--device``, exclusive options,
the excitation on the DFT grid) and the scene and ``--set``/``--vary`` values of ``run``,
``sweep`` and ``paper``.

``_CROSS[command](args)`` raises ``ValueError`` naming the options at fault; commands without
cross-option rules have no entry.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

from . import scene as _scene
from ._cli_checks_io import check_model_matches_device
from ._cli_checks_rules import MOVE_LIMIT_M, SEED, _int, between, ge, gt, int_ge
from ._cli_checks_scene import check_scene, load_scene_checked
from ._cli_device import variant_flags
from .experiment._excitation import check_on_grid, paper_frequencies


# ---- cross-option rules ---------------------------------------------------------------------
def _protocol_cross(a):
    f = paper_frequencies() if a.freqs == "paper" else [float(x) for x in a.freqs.split(",")]
    try:
        check_on_grid(f, a.fs, a.period)
    except ValueError as e:
        raise ValueError(f"--freqs/--fs/--period: {e}") from None


def _band_cross(a):
    lo, hi = getattr(a, "f_min_hz", None), getattr(a, "f_max_hz", None)
    if lo is not None and hi is not None and lo >= hi:
        raise ValueError(f"--f-min-hz ({lo:g}) must be < --f-max-hz ({hi:g})")


def _fit_cross(a):
    _band_cross(a)
    if getattr(a, "method", None) == "ml" and getattr(a, "solver", None) == "jaxopt_lm":
        raise ValueError(
            "--solver jaxopt_lm is for --method nls only (ML takes an optimistix solver: "
            "lm, dogleg, gauss_newton, bfgs, nonlinear_cg)"
        )


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
            from . import sweep as _sweep  # local: CLI start-up (hapid.fit, optimistix)

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
    from . import sweep as _sweep  # local: CLI start-up (hapid.fit, optimistix)

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
          "sweep": _sweep_cross, "fit": _fit_cross, "frf": _band_cross,
          "predict": _band_cross, "plant": _band_cross}  # fmt: skip


def _parse_value(val: str):
    try:
        return json.loads(val)
    except json.JSONDecodeError:
        return val
