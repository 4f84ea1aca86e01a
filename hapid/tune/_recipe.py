"""The end-to-end recipe behind ``hapid tune``: :func:`robust_design` takes a model, draws of the
plant, the evidence and a :class:`Recipe`, tunes g and returns a :class:`RobustDesign`.

Families (see :class:`.Family`):

* ``posterior`` — the draws (:class:`~hapid.uncertainty.ParamDraws`: posterior samples, with
  their model-error term or not; :class:`~hapid.uncertainty.LoopDraws`: the loop conditioned
  on the measured FRF, closed at the controller's rate when it is known). They constrain the
  margins for a fraction ``quantile`` of the draws (CVaR); the bandwidth only with
  ``posterior_bandwidth`` or when there is no device.
* ``device`` (with ``device``) — the simulated device's true sampled plants at other stylus
  poses and virtual subjects, not the nominal plant (kept for validation). Margins for all,
  bandwidth for the median.
* ``frf`` (with ``evidence``) — the measured loop ``P_meas G`` kept out of the disc around −1
  at every measured frequency, and the loop small-gain beyond the top measured frequency
  (:mod:`hapid.tune._evidence`).

Validation (:func:`.validate`) re-checks the start and the tuned g on held-out draws, the
nominal true plant, held-out variants and the sampled loop in the time domain; the decision
table (:mod:`hapid.tune._decision`) chooses the design returned.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from .._grids import continuous_grid as posterior_grid
from .._plain import jsonable
from ..control import Compensator
from ..defaults import (
    TUNE_MAX_STEPS,
    TUNE_N_HOLDOUT,
    TUNE_N_SUBJECTS,
    TUNE_N_TRAIN,
    TUNE_PM_ALLOWANCE_DEG,
    TUNE_QUANTILE,
)
from ..uncertainty._draws import LoopDraws, ParamDraws
from ..verdict import Check, Verdict
from ._check import FRF_FLOOR, design_check, loop_label
from ._decision import (
    Choice,
    Decision,
    certified_fallback,
    compare,
    holdout_check,
    meets_chance,
    training_decision,
)
from ._evidence import KAPPA, beyond_grid, certificate, evidence_from_frf
from ._objective import Family, Requirements
from ._params import ParamMap
from ._progress import note
from ._recipe_plants import device_family, draw_family, held_out_variants
from ._scenarios import make_scenarios
from ._tune import TuneResult, tune
from ._validate import table_row, validate

__all__ = ["Recipe", "RobustDesign", "posterior_grid", "robust_design"]


@dataclasses.dataclass(frozen=True)
class Recipe:
    """How :func:`robust_design` builds its families, tunes and re-checks.

    - ``n_train``, ``n_holdout``: training and held-out draws; ``quantile``: the chance level
      the margins must hold at on the draws.
    - ``n_subjects``, ``n_holdout_subjects``: virtual subjects among the device's training and
      held-out variants.
    - ``n_freq``: points of the training grid; ``dense_factor``: the grid-exchange grid has
      ``dense_factor · n_freq`` points (1: no exchange); ``n_holdout_freq``: points of the
      held-out draws' grid.
    - ``mu_schedule``, ``max_steps``: the continuation penalties and BFGS steps per stage.
    - ``keep_dc_gain``: ``|g(0)|`` may not drop below the start's.
    - ``validate``: re-check and decide (else the tuner's g is returned unchecked).
    - ``posterior_bandwidth``: the draws also claim the bandwidth (median draw).
    - ``evidence_bandwidth``: the measured FRF claims the bandwidth instead of the median
      draw (no device, draws keep the margins).
    - ``kappa``: the small-gain bound beyond the evidence; ``mismatch``: a bound on
      ``σ̄(P P̂⁻¹)`` there (default: its largest measured value in the top half-octave).
    - ``certified_fallback``: when the chosen g is not certified, scale the gains to what
      the evidence certifies (:func:`hapid.tune._decision.certified_fallback`).
    - ``seed``: draws, subsets and variants.
    """

    n_train: int = TUNE_N_TRAIN
    n_holdout: int = TUNE_N_HOLDOUT
    quantile: float = TUNE_QUANTILE
    n_subjects: int = TUNE_N_SUBJECTS
    n_holdout_subjects: int = 4
    n_freq: int = 300
    dense_factor: int = 4
    n_holdout_freq: int = 600
    mu_schedule: tuple = (100.0, 1e3, 1e4)
    max_steps: int = TUNE_MAX_STEPS
    keep_dc_gain: bool = True
    validate: bool = True
    posterior_bandwidth: bool = False
    evidence_bandwidth: bool = False
    kappa: float = KAPPA
    mismatch: float | None = None
    certified_fallback: bool = True
    seed: int = 0

    def __post_init__(self):
        if not 0.0 < self.quantile <= 1.0:
            raise ValueError(f"Recipe: quantile must be in (0, 1], got {self.quantile}")
        for k in ("n_train", "n_holdout", "n_freq", "dense_factor", "max_steps"):
            if int(getattr(self, k)) < 1:
                raise ValueError(f"Recipe: {k} must be ≥ 1, got {getattr(self, k)}")


@dataclasses.dataclass(frozen=True)
class RobustDesign:
    """What :func:`robust_design` returns.

    - ``result``: the returned design (:class:`.TuneResult`; ``result.g`` the returned g,
      ``result.check`` its three-valued verdict); ``candidate``: the tuner's own g's result.
    - ``decision``: :class:`hapid.tune._decision.Decision` (which g and why).
    - ``families``: sizes and construction of the training and held-out families (JSON).
    - ``table``: re-check rows ``{"start", "tuned"[, "returned"]}`` (:func:`.table_row` plus
      the evidence certificate); ``validation``: ``{"start", "tuned"}`` :class:`.Validation`.
      Both empty without validation.
    - ``loop``: the loop the verdict holds for (continuous, or the controller's rate).
    """

    result: TuneResult
    candidate: TuneResult
    decision: Decision
    families: dict
    table: dict = dataclasses.field(default_factory=dict)
    validation: dict = dataclasses.field(default_factory=dict)
    loop: str | None = None

    @property
    def g(self) -> Compensator:
        """The returned g."""
        return self.result.g

    @property
    def check(self) -> Check | None:
        """The returned design's three-valued verdict (``None`` without validation)."""
        return self.result.check

    @property
    def kept_start(self) -> bool:
        """The start g is returned unchanged."""
        return self.decision.choice == Choice.START

    @property
    def returned_row(self) -> dict:
        """The re-check row of the returned design (``{}`` without validation)."""
        t = self.table
        return t.get("returned") or t.get("start" if self.kept_start else "tuned") or {}

    @property
    def status(self) -> Verdict:
        """The returned design's verdict; ``NOT_ESTABLISHED`` when it was not re-checked."""
        return Verdict.NOT_ESTABLISHED if self.check is None else self.check.verdict

    @property
    def ok(self) -> bool:
        """The returned design passed its re-check."""
        return self.status == Verdict.PASSED

    def summary(self) -> dict:
        """Strict-JSON: claimed bandwidths, constraints, history, parameters, families,
        re-check table, loop, decision and verdict (what a design file stores)."""
        r = self.result
        out = {"status": self.status, "ok": self.ok, "bandwidth_claimed_hz": r.bandwidth_hz,
               "bandwidth0_claimed_hz": r.bandwidth0_hz, "constraints": r.constraints,
               "feasible": r.feasible, "history": r.history, "parameters": r.parameters(),
               "families": self.families, "wall_s": r.wall_s, "table": self.table,
               "loop": self.loop, "decision": self.decision.summary()}  # fmt: skip
        if self.check is not None:
            c = self.check
            out |= {"verdict": c.verdict.value, "reason": c.reason, "remedy": c.remedy}
        return jsonable(out)


def _with_g(res: TuneResult, g: Compensator, **kw) -> TuneResult:
    return dataclasses.replace(res, g=g, x=np.asarray(ParamMap.from_template(g).vector(g)), **kw)


def robust_design(
    model,
    draws: ParamDraws | LoopDraws | None = None,
    *,
    evidence=None,
    device=None,
    g0: Compensator | None = None,
    requirements: Requirements | None = None,
    recipe: Recipe | None = None,
    ts: float | None = None,
    progress=None,
) -> RobustDesign:
    """Tune g for ``model`` over ``draws`` and/or ``device`` variants, holding it on the
    ``evidence``, then re-check the start and the tuned g and decide (module docstring).

    - ``draws``: :class:`~hapid.uncertainty.ParamDraws` or
      :class:`~hapid.uncertainty.LoopDraws` (``None``: the device family only).
    - ``evidence``: the measured FRF (:class:`~hapid.frf.FRF` or dict with ``omega, Z_H,
      Z_T``), every measured frequency. Default: the loop draws' own FRF; none for parameter
      draws. Without evidence the verdict cannot be "passed" unless a device is given.
    - ``device``: a simulated device: its variants train, its true plant re-checks.
    - ``g0``: the start (default the paper's g); ``requirements``: margins (default 6 dB /
      30°); ``recipe``: :class:`Recipe`.
    - ``ts``: the controller's sampling period (s) for the loop draws, the evidence and the
      verdict (default the device's, else continuous).

    The chance-constrained families train with the PM requirement raised by
    ``TUNE_PM_ALLOWANCE_DEG``; the re-check and the verdict use the requirement asked for.
    Raises ``ValueError`` with neither draws nor a device, ``TypeError`` for other draws.
    """
    r = Recipe() if recipe is None else recipe
    if draws is None and device is None:
        raise ValueError("robust_design: give draws (ParamDraws or LoopDraws), a device, or both")
    if draws is not None and not isinstance(draws, ParamDraws | LoopDraws):
        raise TypeError(f"robust_design: draws must be ParamDraws or LoopDraws, got "
                        f"{type(draws).__name__}")  # fmt: skip
    if evidence is None and isinstance(draws, LoopDraws):
        evidence = draws.measured
    g0 = Compensator.paper() if g0 is None else g0
    if ts is None and device is not None:  # the loop the device closes: its rate
        ts = float(device.ts)
    req = Requirements() if requirements is None else requirements
    if r.keep_dc_gain and req.min_dc_gain is None:  # static accuracy no worse than the start's
        req = dataclasses.replace(req, min_dc_gain=float(np.abs(g0(np.array([0.0]))[0])))
    rng = np.random.default_rng(r.seed)
    note(progress, "building the training plants")
    families, info, hold_models, om_h = [], {}, None, None
    if draws is not None:
        fam, hold_models, om_h, info["posterior"] = draw_family(draws, model, r, rng, ts)
        families.append(fam)
    variants = None
    if device is not None:
        fam, info["device"] = device_family(device, model, r)
        families.append(fam)
        if r.validate:
            variants = held_out_variants(device, r)
            info["device"]["held_out"] = len(variants[0])
    if device is None:
        families[0] = dataclasses.replace(families[0], bandwidth=True, bw_quantile=0.5)
    # the box of g's frequencies as without the evidence family (whose grid ends at ω_e)
    f_max_hz = (0.45 * device.fs_hz if device is not None
                else float(posterior_grid(r.n_freq)[-1]) / TWO_PI / 4.0)  # fmt: skip
    ev = None
    if evidence is not None:
        ev = evidence_from_frf(evidence, model, mismatch=r.mismatch, kappa=r.kappa, ts=ts)
        families.append(Family(make_scenarios(ev.P, model, ev.omega, ts=ev.ts), quantile=1.0,
                               bandwidth=r.evidence_bandwidth, name="frf", contour=False))  # fmt: skip
        if r.evidence_bandwidth and device is None and not r.posterior_bandwidth:
            families[0] = dataclasses.replace(families[0], bandwidth=False)
        req = dataclasses.replace(req, sg_omega=tuple(beyond_grid(ev)), sg_g_max=ev.g_max,
                                  sg_ts=ev.ts)  # fmt: skip
        info["evidence"] = {"source": ev.source, "n_freq": int(ev.omega.size),
                            "evidence_hz": ev.omega_e / TWO_PI, "mismatch_bound": ev.mismatch,
                            "kappa": ev.kappa}  # fmt: skip
    note(
        progress,
        f"tuning on {', '.join(f'{f.name} ({f.scenarios.n_scenarios})' for f in families)}",
    )
    train_req = req  # chance-constrained families train with the PM allowance
    if any(f.quantile < 1.0 for f in families):
        train_req = dataclasses.replace(req, pm_deg=req.pm_deg + TUNE_PM_ALLOWANCE_DEG)
    res = tune(families, g0, requirements=train_req, mu_schedule=r.mu_schedule,
               max_steps=r.max_steps, f_max_hz=f_max_hz, progress=progress)  # fmt: skip
    start = dataclasses.replace(res, g=g0, x=res.x0)
    trained = training_decision(res)
    if not r.validate:
        if trained.keeps_tuned:
            return RobustDesign(
                res, res, Decision(Choice.TUNED, "not validated", "not validated"), info
            )
        return RobustDesign(dataclasses.replace(start, training=res.training0), res, trained, info)
    # the held-out draws: on the loop draws' grid and rate, else the wide continuous grid
    omega_c, hold_ts = posterior_grid(), None
    if isinstance(hold_models, np.ndarray):
        omega_c = posterior_grid(r.n_holdout_freq)
    if om_h is not None:
        omega_c, hold_ts = om_h, ts
    table, validation = {}, {}
    for name, g in (("start", g0), ("tuned", res.g)):
        note(progress, f"re-checking the {name} g (held-out plants, true plant)")
        t0 = time.perf_counter()
        v = validate(g, model, samples=hold_models, device=device, variants=variants,
                     omega_c=omega_c, gm_db=req.gm_db, pm_deg=req.pm_deg,
                     p_required=r.quantile, ts=hold_ts)  # fmt: skip
        validation[name] = v
        table[name] = table_row(v) | {"validate_s": time.perf_counter() - t0}
        if ev is not None:
            table[name] |= certificate(ev, model, g, floor=FRF_FLOOR).figures()
    # the training verdict decides first; then the table on the held-out evidence
    decision = compare(table["start"], table["tuned"]) if trained.keeps_tuned else trained
    out = res if decision.keeps_tuned else start
    chosen = table["tuned" if decision.keeps_tuned else "start"]
    if (ev is not None and r.certified_fallback
            and not (chosen.get("certified", True) and meets_chance(chosen, r.quantile))):  # fmt: skip
        note(progress, "not certified: trying the certified-gain fallback")
        cands = (("start", g0), ("tuned", res.g)) if trained.keeps_tuned else (("start", g0),)
        check = holdout_check(model, hold_models, device, variants, omega_c, req, r.quantile,
                              hold_ts)  # fmt: skip
        fb = certified_fallback(cands, ev, model, check, chosen=chosen, quantile=r.quantile)
        if fb is not None:
            decision, g_fb, table["returned"] = fb
            out = _with_g(res, g_fb)
    row = table.get("returned") or table["tuned" if decision.keeps_tuned else "start"]
    ck = design_check(row, gm_db=req.gm_db, pm_deg=req.pm_deg, quantile=r.quantile, ts=ts,
                      g_max=None if ev is None else ev.g_max,
                      frequencies_hz=() if ev is None else np.asarray(ev.omega) / TWO_PI)  # fmt: skip
    return RobustDesign(dataclasses.replace(out, check=ck), res, decision, info, table,
                        validation, loop_label(ts))  # fmt: skip
