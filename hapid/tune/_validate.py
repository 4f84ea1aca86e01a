"""The non-smooth re-check of a (tuned) compensator: did the optimizer fool itself?

Every verdict here comes from the project's reference analyses, not from the smooth
surrogates the tuner optimized:

* **held-out posterior samples** — :func:`hapid.uncertainty.robust_check` of the continuous
  loop ``P̂_s · g Ẑ_T Ẑ_H⁻¹`` (generalized Nyquist verdict first, then loci GM/PM, disk
  margin, first-crossing isotropic bandwidth), on samples not used in tuning;
* **the true plant** — :func:`hapid.control.analyze_loop` of the simulated device's sampled
  plant with the discretized controller (as the paper summary does);
* **held-out device variants** — the same for other stylus poses / virtual subjects;
* **time domain** — :func:`hapid.closed_loop.closed_loop` eigenvalues (an independent
  stability verdict) and a force step through :func:`hapid.closed_loop.simulate_loop`.
"""

from __future__ import annotations

import numpy as np

from .. import (
    _config,  # noqa: F401  (float64)
    pipeline,
)
from .._grids import nyquist_grid as device_grid
from ..closed_loop import closed_loop, simulate_loop
from ..control import Compensator
from ..defaults import GM_DB, PM_DEG
from ..uncertainty import posterior_omega, robust_check

_LOOP_KEYS = ("stable", "iso_bandwidth_hz", "gm_db", "pm_deg", "disk_margin", "disk_gm_db",
              "disk_pm_deg", "t_peak_db", "t_peak_hz", "nyquist_resolved")  # fmt: skip


def _clean(d):
    out = {}
    for k, v in d.items():
        if isinstance(v, bool | str) or v is None:
            out[k] = v
        elif isinstance(v, int | np.integer):
            out[k] = int(v)
        else:
            out[k] = float(v)
    return out


def true_plant_loop(g: Compensator, model, device, omega=None, spec=None) -> dict:
    """Loop numbers of the discretized controller with ``device.sampled_P`` (Nyquist first).
    ``spec`` (default :data:`hapid.pipeline.SPEC_VALIDATE`): what the report computes —
    :data:`hapid.pipeline.SPEC_FIGURES` adds the per-frequency arrays for plots."""
    omega = device_grid(device.fs_hz) if omega is None else np.asarray(omega, dtype=float)
    rep = pipeline.loop(
        pipeline.controller(model, g, ts=device.ts),
        pipeline.device_plant(device, omega),
        pipeline.SPEC_VALIDATE if spec is None else spec,
    )
    s = rep.numbers()
    return _clean({k: s[k] for k in _LOOP_KEYS}) | {"report": rep}


def step_response(g: Compensator, model, device, *, n_samples: int = 800, direction=None) -> dict:
    """Closed-loop eigenvalue verdict and a 1 N force step (sampled loop with delay).

    Returns ``stable`` (spectral radius < 1), ``spectral_radius``, and for the step along
    ``direction`` (default rod 1): ``overshoot`` (peak/final − 1 of the stepped channel),
    ``final_error`` (|1 − final value|, mean of the last 10 %), ``coupling`` (largest
    off-direction |R_I| over the run), ``settle_s`` (last time outside ±5 % of the final
    value), ``R_D``, ``R_I`` arrays, ``t`` (s).
    """
    ctrl = pipeline.controller(model, g, ts=device.ts).discrete()
    cl = closed_loop(device, ctrl)
    rho = float(cl.spectral_radius())
    n = device.n
    e = np.zeros(n)
    if direction is None:
        e[0] = 1.0
    else:
        e = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    k0 = 20
    R_D = np.zeros((n_samples, n))
    R_D[k0:] = e
    out = simulate_loop(device, ctrl, R_D)
    R_I = np.asarray(out["R_I"])
    y = R_I @ e
    tail = y[-max(1, n_samples // 10) :]
    final = float(np.mean(tail))
    ok = bool(np.all(np.isfinite(R_I))) and rho < 1.0
    perp = R_I - np.outer(y, e)
    band = np.abs(y[k0:] - final) > 0.05 * max(abs(final), 1e-12)
    last = np.nonzero(band)[0]
    return {
        "stable": ok,
        "spectral_radius": rho,
        "overshoot": float(np.max(y[k0:]) / final - 1.0) if ok and final != 0 else float("nan"),
        "final_error": float(abs(1.0 - final)) if ok else float("nan"),
        "coupling": float(np.max(np.abs(perp))) if ok else float("nan"),
        "settle_s": float((last[-1] + 1) * device.ts) if ok and last.size else 0.0,
        "t": np.arange(n_samples) * device.ts,
        "R_D": R_D,
        "R_I": R_I,
    }


def validate(
    g: Compensator,
    model,
    *,
    samples=None,
    device=None,
    variants=None,
    omega_c=None,
    omega_d=None,
    gm_db: float = GM_DB,
    pm_deg: float = PM_DEG,
    p_required: float = 0.95,
    time_domain: bool = True,
    ts: float | None = None,
) -> dict:
    """Non-smooth verdicts of ``g`` with the nominal ``model`` (module docstring).

    - ``samples``: held-out posterior models (a batched :class:`~hapid.impedance.ImpedanceModel`
      or :class:`~hapid.uncertainty.PosteriorSamples`), analysed on ``omega_c`` (default
      :func:`hapid.uncertainty.posterior_omega`, the wide grid that resolves the Nyquist
      count of continuous loops; the 0.05–450 Hz grid miscounted most cu5 draws). With
      ``ts`` (s) and plant arrays ``(S, N, n, n)`` on ``omega_c`` (a grid to ``π/ts``), the
      loop is closed with the controller discretized at ``ts`` (the loop the device runs).
    - ``device``: the simulated device (true plant, time domain); ``variants``: ``(labels,
      P)`` of held-out device variants on ``omega_d`` (default :func:`device_grid`).

    Returns a dict with ``posterior`` / ``variants`` (RobustReport summaries, ``report``
    the full report), ``true_plant`` (loop numbers) and ``time_domain``.
    """
    out: dict = {}
    if samples is not None:
        omc = posterior_omega() if omega_c is None else np.asarray(omega_c, dtype=float)
        kw = dict(gm_db=gm_db, pm_deg=pm_deg, p_stable_required=p_required, max_samples=None,
                  metrics="all")  # fmt: skip
        if ts is None:
            rep = robust_check(samples, (model, g), omc, **kw)
        else:
            ctrl = pipeline.controller(model, g, ts=ts)
            rep = robust_check(np.asarray(samples), np.asarray(ctrl.response(omc)), omc,
                               controller_rhp=int(ctrl.p_rhp), **kw)  # fmt: skip
        out["posterior"] = rep.numbers() | {"report": rep}
    if device is not None:
        omd = device_grid(device.fs_hz) if omega_d is None else np.asarray(omega_d, dtype=float)
        out["true_plant"] = true_plant_loop(g, model, device, omd)
        if variants is not None:
            labels, P = variants
            ctrl = pipeline.controller(model, g, ts=device.ts)
            G = np.asarray(ctrl.response(omd))
            rep = robust_check(np.asarray(P), G, omd, controller_rhp=int(ctrl.p_rhp),
                               gm_db=gm_db, pm_deg=pm_deg, p_stable_required=p_required, labels=labels,
                               backend="metrics", metrics="all")  # fmt: skip
            out["variants"] = rep.numbers() | {"report": rep}
        if time_domain:
            out["time_domain"] = step_response(g, model, device)
    return out


def table_row(v: dict) -> dict:
    """The headline numbers of a :func:`validate` result, flat and JSON-able."""
    row = {}
    if "true_plant" in v:
        t = v["true_plant"]
        row |= {
            f"true_{k}": t[k]
            for k in ("stable", "iso_bandwidth_hz", "gm_db", "pm_deg", "disk_margin", "t_peak_db")
        }
    for fam in ("posterior", "variants"):
        if fam in v:
            s = v[fam]
            row |= {
                f"{fam}_n": s["n"],
                f"{fam}_p_stable": s["p_stable"],
                f"{fam}_passed": s["passed"],
            }
            for k in (
                "iso_bandwidth_hz_q05",
                "iso_bandwidth_hz_q50",
                "gm_db_q05",
                "pm_deg_q05",
                "disk_margin_q05",
            ):
                row[f"{fam}_{k}"] = s[k]
            rep = v[fam]["report"]
            ok = (
                rep.stable
                & (rep.penalized("gm_db") >= rep.gm_req_db)
                & (rep.penalized("pm_deg") >= rep.pm_req_deg)
            )
            row[f"{fam}_frac_meeting_margins"] = float(np.mean(ok))
    if "time_domain" in v:
        t = v["time_domain"]
        row |= {
            f"step_{k}": t[k]
            for k in (
                "stable",
                "spectral_radius",
                "overshoot",
                "final_error",
                "coupling",
                "settle_s",
            )
        }
    return row
