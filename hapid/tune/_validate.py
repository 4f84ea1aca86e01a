"""The non-smooth re-check of a (tuned) compensator: did the optimizer fool itself?

Every verdict here comes from the non-smooth loop analyses, not from the smooth surrogates
the tuner optimized:

* **held-out posterior samples** — :func:`hapid.uncertainty.robust_check` of the continuous
  loop ``P̂_s · g Ẑ_T Ẑ_H⁻¹`` (generalized Nyquist verdict first, then loci GM/PM, disk
  margin, first-crossing isotropic bandwidth), on samples not used in tuning;
* **the true plant** — :func:`hapid.pipeline.loop` (the :func:`hapid.control.loop_metrics`
  path every command uses: generalized Nyquist verdict, refined crossings) of the simulated
  device's sampled plant with the discretized controller (as the paper summary does);
* **held-out device variants** — the same for other stylus poses / virtual subjects;
* **time domain** — :func:`hapid.closed_loop.closed_loop` eigenvalues (an independent
  stability verdict) and a force step through :func:`hapid.closed_loop.simulate_loop`.
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from .. import (
    _config,  # noqa: F401  (float64)
    pipeline,
)
from .._grids import nyquist_grid as device_grid
from .._plain import jsonable
from ..closed_loop import closed_loop, simulate_loop
from ..control import Compensator
from ..defaults import GM_DB, PM_DEG
from ..uncertainty import posterior_omega, robust_check
from ..uncertainty._cover import deciding_pm_hz
from ..verdict import Verdict, combine


def true_plant_loop(g: Compensator, model, device, omega=None, spec=None):
    """The loop of the discretized controller with ``device.sampled_P`` (Nyquist first): a
    :class:`hapid.control.LoopMetrics` (its :meth:`~hapid.control.LoopMetrics.numbers` for
    plain numbers). ``omega`` (rad/s, default :func:`device_grid`); ``spec`` (default
    :data:`hapid.pipeline.SPEC_VALIDATE`): what the report computes —
    :data:`hapid.pipeline.SPEC_FIGURES` adds the per-frequency arrays for plots."""
    omega = device_grid(device.fs_hz) if omega is None else np.asarray(omega, dtype=float)
    return pipeline.loop(
        pipeline.controller(model, g, ts=device.ts),
        pipeline.device_plant(device, omega),
        pipeline.SPEC_VALIDATE if spec is None else spec,
    )


class StepStatus(enum.StrEnum):
    """The time-domain verdict of :class:`StepResponse`: the sampled closed loop's spectral
    radius below 1 and a finite step response (``stable``), or not (``unstable``)."""

    STABLE = "stable"
    UNSTABLE = "unstable"


@dataclasses.dataclass(frozen=True)
class StepResponse:
    """Result of :func:`step_response`: ``stable`` (spectral radius < 1 and a finite
    response), ``spectral_radius``, for the step along the chosen direction ``overshoot``
    (peak/final − 1 of the stepped channel), ``final_error`` (|1 − final value|, mean of the
    last 10 %), ``coupling`` (largest off-direction |R_I| over the run), ``settle_s`` (last
    time outside ±5 % of the final value; NaN figures when not stable), and the arrays ``t``
    (s, ``(T,)``), ``R_D``, ``R_I`` (``(T, n)``)."""

    stable: bool
    spectral_radius: float
    overshoot: float
    final_error: float
    coupling: float
    settle_s: float
    t: np.ndarray
    R_D: np.ndarray
    R_I: np.ndarray

    @property
    def status(self) -> StepStatus:
        return StepStatus.STABLE if self.stable else StepStatus.UNSTABLE

    @property
    def ok(self) -> bool:
        return self.status is StepStatus.STABLE

    def numbers(self) -> dict:
        """The scalar figures (NaN kept), then ``status`` and ``ok``."""
        keys = ("stable", "spectral_radius", "overshoot", "final_error", "coupling", "settle_s")
        return {k: getattr(self, k) for k in keys} | {"status": self.status.value, "ok": self.ok}

    def summary(self) -> dict:
        """Strict-JSON dict: :meth:`numbers` with non-finite values as ``None`` (no arrays)."""
        return jsonable(self.numbers())


def step_response(
    g: Compensator, model, device, *, n_samples: int = 800, direction=None
) -> StepResponse:
    """Closed-loop eigenvalue verdict and a 1 N force step along ``direction`` (default rod
    1) of ``n_samples`` samples (sampled loop with delay): a :class:`StepResponse`."""

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
    return StepResponse(
        stable=ok,
        spectral_radius=rho,
        overshoot=float(np.max(y[k0:]) / final - 1.0) if ok and final != 0 else float("nan"),
        final_error=float(abs(1.0 - final)) if ok else float("nan"),
        coupling=float(np.max(np.abs(perp))) if ok else float("nan"),
        settle_s=float((last[-1] + 1) * device.ts) if ok and last.size else 0.0,
        t=np.arange(n_samples) * device.ts,
        R_D=R_D,
        R_I=R_I,
    )


@dataclasses.dataclass(frozen=True)
class Validation:
    """Result of :func:`validate`; a part not checked is ``None``.

    ``posterior``, ``variants``: :class:`~hapid.uncertainty.RobustReport` of the held-out
    posterior models and device variants; ``true_plant``: the
    :class:`~hapid.control.LoopMetrics` of :func:`true_plant_loop`; ``time_domain``: the
    :class:`StepResponse`; ``gm_db``, ``pm_deg``: the margin requirements.

    ``status`` (:class:`hapid.verdict.Verdict`) combines :meth:`verdicts`: ``failed`` if any
    part failed, else ``not established`` if any is (or nothing was checked), else
    ``passed``."""

    posterior: object = None
    true_plant: object = None
    variants: object = None
    time_domain: StepResponse | None = None
    gm_db: float = GM_DB
    pm_deg: float = PM_DEG

    def verdicts(self) -> dict:
        """:class:`~hapid.verdict.Verdict` per part checked: the robust reports' own; the
        true plant ``passed`` when its loop is stable with ``|GM| ≥ gm_db`` and
        ``|PM| ≥ pm_deg``, ``not established`` when its Nyquist count is unresolved, else
        ``failed``; the time domain ``passed`` when stable."""
        out = {}
        if self.posterior is not None:
            out["posterior"] = self.posterior.status
        if self.true_plant is not None:
            t = self.true_plant.numbers()
            if t["status"] == "unresolved":
                out["true_plant"] = Verdict.NOT_ESTABLISHED
            else:
                met = t["ok"] and abs(t["gm_db"]) >= self.gm_db and abs(t["pm_deg"]) >= self.pm_deg
                out["true_plant"] = Verdict.PASSED if met else Verdict.FAILED
        if self.variants is not None:
            out["variants"] = self.variants.status
        if self.time_domain is not None:
            out["time_domain"] = Verdict.PASSED if self.time_domain.ok else Verdict.FAILED
        return out

    @property
    def status(self) -> Verdict:
        v = self.verdicts().values()
        return combine(v) if v else Verdict.NOT_ESTABLISHED  # nothing checked

    @property
    def ok(self) -> bool:
        return self.status is Verdict.PASSED

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``verdicts`` (part → verdict), the
        requirements, and each part's own ``summary()`` (``None``: not checked)."""
        parts = ("posterior", "true_plant", "variants", "time_domain")
        out = {"status": self.status, "ok": self.ok, "verdicts": self.verdicts(),
               "requirements": {"gm_db": self.gm_db, "pm_deg": self.pm_deg}}  # fmt: skip
        for k in parts:
            part = getattr(self, k)
            out[k] = None if part is None else part.summary()
        return jsonable(out)


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
) -> Validation:
    """Non-smooth verdicts of ``g`` with the nominal ``model`` (module docstring).

    - ``samples``: held-out posterior models (a batched :class:`~hapid.impedance.ImpedanceModel`
      or :class:`~hapid.uncertainty.PosteriorSamples`), analysed on ``omega_c`` (default
      :func:`hapid.uncertainty.posterior_omega`, the wide grid that resolves the Nyquist
      count of continuous loops; the 0.05–450 Hz grid miscounted most cu5 draws). With
      ``ts`` (s) and plant arrays ``(S, N, n, n)`` on ``omega_c`` (a grid to ``π/ts``), the
      loop is closed with the controller discretized at ``ts`` (the loop the device runs).
    - ``device``: the simulated device (true plant, time domain); ``variants``: ``(labels,
      P)`` of held-out device variants on ``omega_d`` (default :func:`device_grid`).

    Returns a :class:`Validation` (``posterior``, ``variants``, ``true_plant``,
    ``time_domain``; ``None`` where not checked).
    """

    out: dict = {"gm_db": float(gm_db), "pm_deg": float(pm_deg)}
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
        out["posterior"] = rep
    if device is not None:
        omd = device_grid(device.fs_hz) if omega_d is None else np.asarray(omega_d, dtype=float)
        out["true_plant"] = true_plant_loop(g, model, device, omd)
        if variants is not None:
            labels, P = variants
            ctrl = pipeline.controller(model, g, ts=device.ts)
            G = np.asarray(ctrl.response(omd))
            rep = robust_check(np.asarray(P), G, omd, controller_rhp=int(ctrl.p_rhp),
                               gm_db=gm_db, pm_deg=pm_deg, p_stable_required=p_required, labels=labels,
                               metrics="all")  # fmt: skip
            out["variants"] = rep
        if time_domain:
            out["time_domain"] = step_response(g, model, device)
    return Validation(**out)


def table_row(v: Validation) -> dict:
    """The headline numbers of a :class:`Validation`, one flat row of plain values (NaN
    kept): ``true_*``, ``posterior_*``, ``variants_*``, ``step_*``."""
    row = {}
    if v.true_plant is not None:
        t = v.true_plant.numbers()
        row |= {
            f"true_{k}": t[k]
            for k in ("stable", "iso_bandwidth_hz", "gm_db", "pm_deg", "disk_margin", "t_peak_db")
        }
    for fam in ("posterior", "variants"):
        rep = getattr(v, fam)
        if rep is not None:
            s = rep.numbers()
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
            ok = (
                rep.stable
                & (rep.penalized("gm_db") >= rep.gm_req_db)
                & (rep.penalized("pm_deg") >= rep.pm_req_deg)
            )
            row[f"{fam}_frac_meeting_margins"] = float(np.mean(ok))
            if rep.pm_freq_hz is not None:  # where the PM quantile is decided (the gap rule)
                row[f"{fam}_pm_deciding_hz"] = deciding_pm_hz(rep)
    if v.time_domain is not None:
        t = v.time_domain.numbers()
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
