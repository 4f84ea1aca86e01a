"""Scenes: a small TOML file names the device, protocol, estimators, controller and outputs.

``run_scene`` computes only the stages the requested outputs need, each cached on disk under a
hash of its inputs (``hapid._stages``): a Z_H figure needs no controller; no MCMC unless a
posterior is asked for; no time-domain simulation unless the protocol says so. Changing one
option recomputes only the stages downstream of it.

Stage graph::

    device ─► run ─► frf ─┬─► wls ─┐                         ┌─► fig5 (SISO σ(T − I))
                          └─► nls ─┴─► mimo ◄─ plant ◄─ device├─► fig9, fig10 (MIMO)
    controller ───────────────────────► mimo, siso ─────────┴─► summary
    frf, wls, nls ─► fig6, fig7, fig8                     posterior ─► robust

Config sections (all optional, defaults = the paper reproduction on ``cu5``):
``[device]`` preset, move (dx, dy, dz, dyaw, dpitch, droll from home), subject_seed,
light_damping, extra_modes, encoder; ``[protocol]`` freqs ("paper" or list, Hz), periods,
transient, pattern, phases, amplitude, seed, noise, position_noise, encoder_res, synthesis
("periodic" | "time_domain"), friction; ``[fit]`` omega_c_hz, positize, weight, f_max_hz,
solver; ``[controller]`` k, lag_zero_hz, lag_pole_hz, notch_hz, zeta_num, zeta_den,
lowpass_hz, siso_gm_db, siso_pm_deg; ``[analysis]`` f_min_hz, n_freq, band_hz;
``[posterior]`` walkers, steps, seed, samples; ``[outputs]`` want = [...], dir.
"""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path

import numpy as np

from ._stages import Graph, Stage

TWO_PI = 2 * np.pi

DEFAULTS: dict = {
    "device": {"preset": "cu5", "move": [0.0] * 6, "subject_seed": None, "light_damping": False,
               "extra_modes": True, "encoder": "motor"},
    "protocol": {"freqs": "paper", "periods": 4, "transient": 1, "pattern": "paper",
                 "phases": "random", "amplitude": 0.3, "seed": 0, "noise": 5e-3,
                 "position_noise": 0.0, "encoder_res": 2e-6, "synthesis": "periodic",
                 "friction": False},
    "fit": {"omega_c_hz": 7.0, "positize": True, "weight": "relative", "f_max_hz": 40.0,
            "solver": "lm"},
    "controller": {"k": 0.85, "lag_zero_hz": 30.0, "lag_pole_hz": 0.6,
                   "notch_hz": [17.0, 55.0, 100.0], "zeta_num": 0.2, "zeta_den": 0.5,
                   "lowpass_hz": [100.0, 200.0], "siso_gm_db": 6.0, "siso_pm_deg": 30.0},
    "analysis": {"f_min_hz": 1e-3, "n_freq": 1500, "band_hz": 30.0},
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


# ---- stage functions ------------------------------------------------------------------------
def _device(o):
    import jax

    from .device import Pose, preset, virtual_subject

    kw = {"extra_modes": o["extra_modes"]}
    if o["preset"] == "cu5":
        kw.update(light_damping=o["light_damping"], encoder=o["encoder"])
    mv = list(o["move"]) + [0.0] * (6 - len(o["move"]))
    dev = preset(o["preset"], pose=Pose().moved(*mv), **kw)
    if o["subject_seed"] is not None:
        import equinox as eqx

        # every preset's first three DOF are the translations the subject ranges describe
        hand = virtual_subject(jax.random.PRNGKey(int(o["subject_seed"])), dev.hand, 3)
        dev = eqx.tree_at(lambda d: d.hand, dev, hand)
    return dev


def _protocol(o):
    from .experiment import Protocol, paper_frequencies

    freqs = paper_frequencies() if o["freqs"] == "paper" else np.asarray(o["freqs"], dtype=float)
    return Protocol(
        freq_hz=tuple(freqs), n_periods=int(o["periods"]), transient_periods=int(o["transient"]),
        pattern=o["pattern"], phases=o["phases"], amplitude=float(o["amplitude"]),
        seed=int(o["seed"]), force_noise=float(o["noise"]),
        position_noise=float(o["position_noise"]), encoder_resolution=float(o["encoder_res"]),
    )  # fmt: skip


def _run(o, device):
    from .experiment import periodic_run, time_domain_run

    prot = _protocol(o)
    if o["synthesis"] == "time_domain" or o["friction"]:
        return time_domain_run(device, prot, friction=bool(o["friction"]))
    if o["synthesis"] != "periodic":
        raise ValueError(f"protocol.synthesis must be 'periodic' or 'time_domain', got {o['synthesis']!r}")
    return periodic_run(device, prot)


def _frf(o, run):
    from .experiment import estimate_frf

    return estimate_frf(run)


def _wls(o, frf):
    from .fit import crhp_report, positize, wls

    raw = wls(frf, omega_c=TWO_PI * float(o["omega_c_hz"]))
    model = positize(raw) if o["positize"] else raw
    before, after = crhp_report(raw), crhp_report(model)
    return {"model": model, "raw": raw,
            "crhp_before": (int(before.hand), int(before.total)),
            "crhp_after": (int(after.hand), int(after.total))}  # fmt: skip


def _nls(o, frf):
    from .fit import fit_nls

    res = fit_nls(frf, weight=o["weight"], f_max_hz=o["f_max_hz"], solver=o["solver"],
                  omega_c=TWO_PI * float(o["omega_c_hz"]))  # fmt: skip
    return {"model": res.model, "result": res, "status": res.status, "steps": int(res.n_steps),
            "cost": float(res.cost)}  # fmt: skip


def compensator(o):
    from .control import Compensator

    return Compensator.paper(
        k=float(o["k"]), lag_zeros=[TWO_PI * float(o["lag_zero_hz"])],
        lag_poles=[TWO_PI * float(o["lag_pole_hz"])],
        notch_omega=[TWO_PI * float(f) for f in o["notch_hz"]],
        notch_zeta_num=float(o["zeta_num"]), notch_zeta_den=float(o["zeta_den"]),
        lowpass=[TWO_PI * float(f) for f in o["lowpass_hz"]],
    )  # fmt: skip


def analysis_grid(o, fs_hz: float) -> np.ndarray:
    """Analysis frequencies (rad/s): log-spaced from ``f_min_hz`` to just below Nyquist, plus
    the Nyquist frequency itself (the discrete loop's contour ends there)."""
    f = np.geomspace(float(o["f_min_hz"]), 0.49999 * fs_hz, int(o["n_freq"]) - 1)
    return TWO_PI * np.append(f, 0.5 * fs_hz)


def _plant(o, device):
    omega = analysis_grid(o, device.fs_hz)
    return {"omega": omega, "P": np.asarray(device.sampled_P(omega)), "ts": device.ts}


def _controller(o):
    return {"g": compensator(o), "gm_db": float(o["siso_gm_db"]), "pm_deg": float(o["siso_pm_deg"])}


def _mimo_one(model, g, plant):
    from .control import analyze_loop, controller_unstable_poles, discretize_controller

    ctrl = discretize_controller(model, g, plant["ts"])
    G = np.asarray(ctrl.at_omega(plant["omega"]))
    # the controller's own RHP poles (CRHP roots of det Ẑ_H, unstable poles of g) count as
    # open-loop unstable poles in the Nyquist criterion; the device plant is stable
    p_ol = int(controller_unstable_poles(model, g))
    rep = analyze_loop(plant["P"], G, plant["omega"], P_ol_rhp=p_ol)
    return {"report": rep, "controller": ctrl, "p_ol": p_ol}


def _mimo(o, plant, wls_out, nls_out, ctrl):
    return {"wls": _mimo_one(wls_out["model"], ctrl["g"], plant),
            "nls": _mimo_one(nls_out["model"], ctrl["g"], plant)}  # fmt: skip


def _siso(o, plant, ctrl):
    from .control import analyze_loop, discretize_compensator, max_siso_gain

    gd = np.asarray(discretize_compensator(ctrl["g"], plant["ts"]).at_omega(plant["omega"]))
    gd = gd.reshape(-1)
    n = plant["P"].shape[-1]
    out = {}
    cmax = float(max_siso_gain(plant["P"], plant["omega"], gd, ctrl["gm_db"], ctrl["pm_deg"]))
    for label, c in (("c=1", 1.0), ("design rule", cmax)):
        if not np.isfinite(c):
            out[label] = {"c": c, "report": None}
            continue
        G = (c * gd)[:, None, None] * np.eye(n)
        out[label] = {"c": c, "report": analyze_loop(plant["P"], G, plant["omega"])}
    return out


STAGES = [
    Stage("device", (), lambda c: c["device"], lambda o: _device(o)),
    Stage("run", ("device",), lambda c: c["protocol"], _run),
    Stage("frf", ("run",), lambda c: {}, _frf),
    Stage("wls", ("frf",), lambda c: {k: c["fit"][k] for k in ("omega_c_hz", "positize")}, _wls),
    Stage("nls", ("frf",), lambda c: {k: c["fit"][k] for k in ("weight", "f_max_hz", "solver", "omega_c_hz")}, _nls),
    Stage("controller", (), lambda c: c["controller"], lambda o: _controller(o)),
    Stage("plant", ("device",), lambda c: c["analysis"], _plant),
    Stage("mimo", ("plant", "wls", "nls", "controller"), lambda c: {}, _mimo),
    Stage("siso", ("plant", "controller"), lambda c: {}, _siso),
]  # fmt: skip


def _out_stage(name, deps, fn):
    return Stage(name, deps, lambda c: {"dir": c["outputs"]["dir"]}, fn, cache=False)


def _fig(num):
    def fn(o, *deps):
        from . import paper

        return paper.figure(num, o["dir"], *deps)

    return fn


OUT_STAGES = [
    _out_stage("fig5", ("siso",), _fig(5)),
    _out_stage("fig6", ("frf", "wls", "nls"), _fig(6)),
    _out_stage("fig7", ("frf", "wls", "nls"), _fig(7)),
    _out_stage("fig8", ("device", "frf", "wls", "nls"), _fig(8)),
    _out_stage("fig9", ("mimo", "plant"), _fig(9)),
    _out_stage("fig10", ("mimo", "device", "nls"), _fig(10)),  # + the tuned-g loop
    _out_stage("summary", ("device", "frf", "wls", "nls", "mimo", "siso"), lambda o, *d: _summary(o["dir"], *d)),
    _out_stage("frf_file", ("frf",), lambda o, frf: _save_frf(o["dir"], frf)),
    _out_stage("model_files", ("wls", "nls"), lambda o, w, n: _save_models(o["dir"], w, n)),
]  # fmt: skip


def _summary(out_dir, *deps):
    from . import paper

    return paper.summary(out_dir, *deps)


def _save_frf(out_dir, frf):
    from . import io

    return str(io.save_frf(Path(out_dir) / "frf.npz", frf))


def _save_models(out_dir, w, n):
    from . import io

    a = io.save_model(Path(out_dir) / "model_wls.npz", w["model"], method="wls+positize")
    b = io.save_model(Path(out_dir) / "model_nls.npz", n["model"], method="nls", status=n["status"],
                      cost=n["cost"], covariance=np.asarray(n["result"].covariance))  # fmt: skip
    return [str(a), str(b)]


_EXTRA_STAGES: list[Stage] = []  # the uncertainty stages register here


def graph() -> Graph:
    return Graph(STAGES + OUT_STAGES + _EXTRA_STAGES)


def run_scene(cfg: dict, outputs=None, *, cache_dir=".hapid_cache/stages", out_dir=None,
              progress=None):  # fmt: skip
    """Compute a scene's outputs. ``cfg`` is a merged config (``load_scene`` / ``merge``);
    ``outputs`` defaults to ``cfg["outputs"]["want"]``. Returns ``(results, log)``."""
    cfg = copy.deepcopy(cfg)
    if out_dir is not None:
        cfg["outputs"]["dir"] = str(out_dir)
    want = list(outputs if outputs is not None else cfg["outputs"]["want"])
    Path(cfg["outputs"]["dir"]).mkdir(parents=True, exist_ok=True)
    return graph().run(cfg, want, cache_dir=cache_dir, progress=progress)


def dumps(obj) -> str:
    return json.dumps(obj, indent=2, default=float)
