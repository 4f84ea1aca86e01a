"""Scenes: a small TOML file names the device, protocol, estimators, controller and outputs.

``run_scene`` computes only the stages the requested outputs need, each cached on disk under a
hash of its inputs and of hapid's source (``hapid._stages``): a Z_H figure needs no
controller; no tuning unless the summary (or fig10) asks for the tuned g; no time-domain
simulation unless the protocol says so. Changing one option recomputes only the stages
downstream of it.

Stage graph::

    device ─► run ─► frf ─┬─► wls ─┐                         ┌─► fig5 (SISO σ(T − I))
                          └─► nls ─┴─► mimo ◄─ plant ◄─ device├─► fig9, fig10 (MIMO)
    controller ───────────────────────► mimo, siso ─────────┴─► summary
    device, nls ─► tuned (g by hapid.tune) ─► tuned_mimo ──────────► summary, fig10
    frf, wls, nls ─► fig6, fig7, fig8

Every stage function composes :mod:`hapid.pipeline` (experiment → frf → fit → controller →
loop); the loop verdict (controller's own RHP poles included) is the pipeline's.

Config sections (all optional, defaults = the paper reproduction on ``cu5``):
``[device]`` preset (cu5, tripod3, quad4, hexapod6, cu5_soft), move (dx, dy, dz, dyaw,
dpitch, droll from home), subject_seed, light_damping, extra_modes, encoder, delay_samples
(actuator delay in samples) and rod_compliance (traction and sensor springs divided by it) —
these two default to the preset's own (unset); ``[protocol]`` freqs ("paper" or list, Hz), periods,
transient, pattern, phases, amplitude, seed, noise, position_noise, encoder_res, synthesis
("periodic" | "time_domain"), friction; ``[fit]`` omega_c_hz, positize, weight, f_max_hz,
solver, max_steps, rtol, atol, ftol, patience, blend_floor, p_weight, pd_eps, init_floor
(the NLS options of :func:`hapid.fit.fit_nls`), boundary_refit (default true: with
``pd_eps = 0``, a fit whose Ẑ_H has a root at ∞ or within 10⁻³ Hz of the imaginary axis —
an inverse-model controller that is improper or marginal — is refitted with
``pd_eps = PD_EPS``, and the summary says so); ``[controller]`` k, lag_zero_hz, lag_pole_hz,
notch_hz, zeta_num, zeta_den, lowpass_hz, siso_gm_db, siso_pm_deg; ``[analysis]`` f_min_hz, n_freq, band_hz;
``[posterior]`` walkers, steps, seed, samples; ``[outputs]`` want = [...], dir.
"""

from __future__ import annotations

import copy
import dataclasses
import enum
import os
import tomllib
from pathlib import Path

import numpy as np

from . import io
from ._grids import nyquist_grid
from ._plain import jsonable
from ._stages import Graph, Stage
from .control import discretize_compensator, max_siso_gain
from .defaults import (
    FIT_BAND_HZ,
    GM_DB,
    NLS_ATOL,
    NLS_MAX_STEPS,
    NLS_RTOL,
    NLS_SOLVER,
    PM_DEG,
    PPHAT_BAND_HZ,
)

DEFAULTS: dict = {
    "device": {"preset": "cu5", "move": [0.0] * 6, "subject_seed": None, "light_damping": False,
               "extra_modes": True, "encoder": "motor", "delay_samples": None,
               "rod_compliance": None},
    "protocol": {"freqs": "paper", "periods": 4, "transient": 1, "pattern": "paper",
                 "phases": "random", "amplitude": 0.3, "seed": 0, "noise": 5e-3,
                 "position_noise": 0.0, "encoder_res": 2e-6, "synthesis": "periodic",
                 "friction": False},
    "fit": {"omega_c_hz": 7.0, "positize": True, "weight": "relative", "f_max_hz": FIT_BAND_HZ,
            "solver": NLS_SOLVER, "max_steps": NLS_MAX_STEPS, "rtol": NLS_RTOL, "atol": NLS_ATOL, "ftol": 1e-8,
            "patience": 20, "blend_floor": 0.02, "p_weight": 1.0, "pd_eps": 0.0,
            "init_floor": 1e-6, "boundary_refit": True},
    "controller": {"k": 0.85, "lag_zero_hz": 30.0, "lag_pole_hz": 0.6,
                   "notch_hz": [17.0, 55.0, 100.0], "zeta_num": 0.2, "zeta_den": 0.5,
                   "lowpass_hz": [100.0, 200.0], "siso_gm_db": GM_DB, "siso_pm_deg": PM_DEG},
    "analysis": {"f_min_hz": 1e-3, "n_freq": 1500, "band_hz": PPHAT_BAND_HZ},
    "posterior": {"walkers": 0, "steps": 3000, "seed": 0, "samples": 400},
    "outputs": {"want": ["summary"], "dir": "out/scene"},
}  # fmt: skip

OUTPUTS = ("fig5", "fig6", "fig7", "fig8", "fig9", "fig10", "summary", "frf_file",
           "model_files")  # fmt: skip


def load_scene(path) -> dict:
    """Read a scene TOML file and merge it over ``DEFAULTS`` (unknown keys are errors)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such scene file")
    with open(path, "rb") as fh:
        try:
            user = tomllib.load(fh)
        except tomllib.TOMLDecodeError as e:
            raise ValueError(f"{path}: invalid TOML ({e})") from None
    return merge(user, source=str(path))


def merge(user: dict, source: str = "scene") -> dict:
    cfg = copy.deepcopy(DEFAULTS)
    for sec, vals in user.items():
        if sec not in cfg:
            raise ValueError(f"{source}: unknown section [{sec}]; known: {sorted(cfg)}")
        if not isinstance(vals, dict):
            raise ValueError(f"{source}: [{sec}] must be a table")
        for k, v in vals.items():
            if k not in cfg[sec]:
                raise ValueError(f"{source}: unknown key {sec}.{k}; known: {sorted(cfg[sec])}")
            cfg[sec][k] = v
    return cfg


def set_option(cfg: dict, dotted: str, value) -> dict:
    """A copy of ``cfg`` with ``section.key`` set to ``value`` (for sweeps)."""
    sec, _, key = dotted.partition(".")
    if sec not in cfg or key not in cfg[sec]:
        raise ValueError(f"unknown option {dotted!r}")
    out = copy.deepcopy(cfg)
    out[sec][key] = value
    return out


# ---- stage functions: each composes hapid.pipeline ------------------------------------------
def _device(o):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    return pipeline.device(o)


def _protocol(o):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    return pipeline.protocol(o)


def _run(o, device):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    return pipeline.experiment(
        device, _protocol(o), synthesis=o["synthesis"], friction=o["friction"]
    )


def _frf(o, run):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    return pipeline.frf(run)


WLS_KEYS = ("omega_c_hz", "positize")
NLS_KEYS = ("weight", "f_max_hz", "solver", "omega_c_hz", "max_steps", "rtol", "atol", "ftol",
            "patience", "blend_floor", "p_weight", "pd_eps", "init_floor")  # fmt: skip


def _wls(o, frf):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    f = pipeline.fit(frf, "wls+positize" if o["positize"] else "wls", omega_c_hz=o["omega_c_hz"])
    return {"fit": f, "model": f.model,
            "crhp_before": (int(f.crhp_hand_raw), int(f.crhp_total_raw)),
            "crhp_after": (int(f.crhp_hand), int(f.crhp_total))}  # fmt: skip


def _nls(o, frf):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    o = dict(o)
    cf = pipeline.control_fit(frf, boundary_refit=o.pop("boundary_refit", True), **o)
    f, refit = cf.fit, cf.refit_pd_eps
    res = f.result
    return {"fit": f, "model": f.model, "result": res, "status": f.status, "steps": int(res.n_steps),
            "cost": float(res.cost), "refit_pd_eps": refit}  # fmt: skip


def compensator(o):
    """g(s) of a scene's ``[controller]`` options (Hz → rad/s)."""
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    return pipeline.compensator(o)


def analysis_grid(o, fs_hz: float) -> np.ndarray:
    """Analysis frequencies (rad/s): log-spaced from ``f_min_hz`` to just below Nyquist, plus
    the Nyquist frequency itself (the discrete loop's contour ends there)."""
    return nyquist_grid(fs_hz, int(o["n_freq"]), float(o["f_min_hz"]))


def _plant(o, device):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    pl = pipeline.device_plant(device, analysis_grid(o, device.fs_hz))
    return {"omega": np.asarray(pl.omega), "P": np.asarray(pl.P), "ts": pl.ts, "plant": pl}


def _controller(o):
    return {"g": compensator(o), "gm_db": float(o["siso_gm_db"]), "pm_deg": float(o["siso_pm_deg"])}


def _mimo_one(model, g, plant):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    ctrl = pipeline.controller(model, g, ts=plant["ts"])
    rep = pipeline.loop(ctrl, plant["plant"], pipeline.SPEC_FIGURES)  # figures 9, 10
    return {"report": rep, "p_ol": int(ctrl.p_rhp)}


def _mimo(o, plant, wls_out, nls_out, ctrl):
    return {"wls": _mimo_one(wls_out["model"], ctrl["g"], plant),
            "nls": _mimo_one(nls_out["model"], ctrl["g"], plant)}  # fmt: skip


def _siso(o, plant, ctrl):
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    gd = np.asarray(
        discretize_compensator(ctrl["g"], plant["ts"]).at_omega(plant["omega"])
    ).reshape(-1)
    n = plant["P"].shape[-1]
    out = {}
    cmax = float(max_siso_gain(plant["P"], plant["omega"], gd, ctrl["gm_db"], ctrl["pm_deg"]))
    for label, c in (("c=1", 1.0), ("design rule", cmax)):
        if not np.isfinite(c):
            out[label] = {"c": c, "report": None}
            continue
        C = pipeline.controller(None, ctrl["g"], kind="siso", c=c, n=n, ts=plant["ts"])
        out[label] = {
            "c": c,
            "report": pipeline.loop(C, plant["plant"], pipeline.SPEC_FIGURES),
        }
    return out


def _tuned(o, device, nls_out):
    from .tune._paper import tuned_design  # local: CLI start-up (hapid.tune, ~0.8 s)

    return tuned_design(device, nls_out["model"], fast=o["fast"])


def _tuned_mimo(o, plant, nls_out, tuned):
    return _mimo_one(nls_out["model"], tuned["g"], plant)


def _fast_flag(c):
    return {"fast": os.environ.get("HAPID_FAST", "0") == "1"}


STAGES = [
    Stage("device", (), lambda c: c["device"], lambda o: _device(o)),
    Stage("run", ("device",), lambda c: c["protocol"], _run),
    Stage("frf", ("run",), lambda c: {}, _frf),
    Stage("wls", ("frf",), lambda c: {k: c["fit"][k] for k in WLS_KEYS}, _wls),
    Stage("nls", ("frf",), lambda c: {k: c["fit"][k] for k in NLS_KEYS + ("boundary_refit",)}, _nls),
    Stage("controller", (), lambda c: c["controller"], lambda o: _controller(o)),
    Stage("plant", ("device",), lambda c: c["analysis"], _plant),
    Stage("mimo", ("plant", "wls", "nls", "controller"), lambda c: {}, _mimo),
    Stage("siso", ("plant", "controller"), lambda c: {}, _siso),
    # the tuned-g column: a short robust tuning of g on the device's pose/subject variants
    Stage("tuned", ("device", "nls"), _fast_flag, _tuned),
    Stage("tuned_mimo", ("plant", "nls", "tuned"), lambda c: {}, _tuned_mimo),
]  # fmt: skip


def _out_stage(name, deps, fn):
    return Stage(name, deps, lambda c: {"dir": c["outputs"]["dir"]}, fn, cache=False)


def _fig(num):
    def fn(o, *deps):
        from . import paper  # local: CLI start-up (hapid.paper pulls hapid.fit)

        return paper.figure(num, o["dir"], *deps)

    return fn


OUT_STAGES = [
    _out_stage("fig5", ("siso",), _fig(5)),
    _out_stage("fig6", ("frf", "wls", "nls"), _fig(6)),
    _out_stage("fig7", ("frf", "wls", "nls"), _fig(7)),
    _out_stage("fig8", ("device", "frf", "wls", "nls"), _fig(8)),
    _out_stage("fig9", ("mimo", "plant"), _fig(9)),
    _out_stage("fig10", ("mimo", "tuned_mimo"), _fig(10)),  # + the tuned-g loop
    _out_stage("summary", ("device", "frf", "wls", "nls", "mimo", "siso", "tuned", "tuned_mimo"),
               lambda o, *d: _summary(o["dir"], *d)),
    _out_stage("frf_file", ("frf",), lambda o, frf: _save_frf(o["dir"], frf)),
    _out_stage("model_files", ("wls", "nls"), lambda o, w, n: _save_models(o["dir"], w, n)),
]  # fmt: skip


def _summary(out_dir, *deps):
    from . import paper  # local: CLI start-up (hapid.paper pulls hapid.fit)

    return paper.summary(out_dir, *deps)


def _save_frf(out_dir, frf):
    return str(io.save_frf(Path(out_dir) / "frf.npz", frf))


def _save_models(out_dir, w, n):
    a = io.save_model(Path(out_dir) / "model_wls.npz", w["model"], method="wls+positize")
    b = io.save_model(Path(out_dir) / "model_nls.npz", n["model"], method="nls", status=n["status"],
                      cost=n["cost"], covariance=np.asarray(n["result"].covariance))  # fmt: skip
    return [str(a), str(b)]


_EXTRA_STAGES: list[Stage] = []  # other modules may register stages here (none do yet)


def graph() -> Graph:
    return Graph(STAGES + OUT_STAGES + _EXTRA_STAGES)


class SceneStatus(enum.StrEnum):
    """How a scene run got its stages: ``computed`` (at least one stage computed) or
    ``cached`` (every stage read from the cache). Both are ok: a stage that fails raises."""

    COMPUTED = "computed"
    CACHED = "cached"


@dataclasses.dataclass(frozen=True)
class SceneRun:
    """Result of :func:`run_scene`. ``results``: stage name → its output (the requested
    outputs and every stage they needed); ``computed``, ``cached``: stage names in run order;
    ``keys``: stage name → its cache key; ``seconds``: stage name → wall time (s)."""

    results: dict
    computed: list
    cached: list
    keys: dict
    seconds: dict

    @property
    def status(self) -> SceneStatus:
        return SceneStatus.COMPUTED if self.computed else SceneStatus.CACHED

    @property
    def ok(self) -> bool:
        return True

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, the stage names (``stages``), ``computed``,
        ``cached``, ``keys`` and ``seconds`` (not the stage outputs)."""
        return jsonable({"status": self.status, "ok": self.ok, "stages": list(self.results),
                         "computed": self.computed, "cached": self.cached, "keys": self.keys,
                         "seconds": self.seconds})  # fmt: skip


def run_scene(cfg: dict, outputs=None, *, cache_dir=".hapid_cache/stages", out_dir=None,
              progress=None) -> SceneRun:  # fmt: skip
    """Compute a scene's outputs. ``cfg`` is a merged config (``load_scene`` / ``merge``);
    ``outputs`` defaults to ``cfg["outputs"]["want"]``. Returns a :class:`SceneRun`."""
    cfg = copy.deepcopy(cfg)
    if out_dir is not None:
        cfg["outputs"]["dir"] = str(out_dir)
    want = list(outputs if outputs is not None else cfg["outputs"]["want"])
    Path(cfg["outputs"]["dir"]).mkdir(parents=True, exist_ok=True)
    results, log = graph().run(cfg, want, cache_dir=cache_dir, progress=progress)
    return SceneRun(results, log["computed"], log["cached"], log["keys"], log["seconds"])
