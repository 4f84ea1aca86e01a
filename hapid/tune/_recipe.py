"""The end-to-end recipe behind ``hapid tune``: build scenario families, tune, re-check.

Families (see :class:`.Family`):

* ``posterior`` — ``n_train`` posterior samples (continuous loops ``P̂_s · g Ẑ_T Ẑ_H⁻¹``)
  or loop draws conditioned on the measured FRF (:func:`.loop_draw_family`: the loop the
  held-out check closes, at the controller's rate when it is known).
  They constrain the **margins** for a fraction ``quantile`` of the samples (CVaR); by
  default they do not claim bandwidth (set ``posterior_bandwidth``): Laplace draws of a
  misspecified fit can be far from the nominal at low frequency, where no g can make
  σ̄(T − I) small.
* ``device`` (with ``device``) — the simulated device's true sampled plants at other stylus
  poses (±4 cm along x, y, z) and ``n_subjects`` virtual subjects, **not** the nominal plant
  (kept for validation). Margins for all of them, bandwidth for the median
  (``bw_quantile``). This family is what makes the tuning see the actuator delay, the
  sampling and the unmodeled modes that a second-order posterior cannot represent.

With ``keep_dc_gain`` the tuned ``|g(0)|`` may not drop below the start's (static force
error no worse than the paper's g; the isotropic bandwidth alone would let the tuner trade
the lag's low-frequency gain for margin).

Validation (:func:`.validate`) uses *held-out* posterior samples (disjoint from the training
draws), the nominal true plant, held-out variants (diagonal poses, other subjects) and the
sampled loop in the time domain — for the start g and the tuned g side by side.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from .._grids import below_nyquist_grid
from .._grids import continuous_grid as posterior_grid
from ..control import Compensator
from ..defaults import TUNE_PM_ALLOWANCE_DEG
from ..uncertainty import device_plants
from ..uncertainty._loopgp import measured_data, measured_loop_gp
from ._check import FRF_FLOOR, design_check, loop_label
from ._evidence import KAPPA, beyond_grid, certificate, evidence_from_frf
from ._objective import Family, Requirements
from ._progress import note
from ._recipe_decision import (
    _certified_fallback,
    _meets_chance,
    certified_gain,
    no_worse,
    pick_fallback,
    training_no_worse,
)
from ._recipe_plants import (
    HOLDOUT_OFFSETS,
    TRAIN_OFFSETS,
    _has_error_term,
    _n_models,
    _sample_models,
    count_grid,
    loop_draw_family,
    posterior_plants,
    predictive_scenario_plants,
)
from ._scenarios import make_scenarios
from ._tune import tune
from ._validate import device_grid, table_row, validate

__all__ = [
    "FRF_FLOOR",
    "HOLDOUT_OFFSETS",
    "TRAIN_OFFSETS",
    "certified_gain",
    "count_grid",
    "no_worse",
    "pick_fallback",
    "posterior_grid",
    "posterior_plants",
    "predictive_scenario_plants",
    "robust_design",
    "training_no_worse",
]


def robust_design(
    model,
    *,
    samples=None,
    device=None,
    g0: Compensator | None = None,
    requirements: Requirements | None = None,
    n_train: int = 150,
    n_holdout: int = 200,
    quantile: float = 0.975,
    posterior_bandwidth: bool = False,
    n_subjects: int = 16,
    n_holdout_subjects: int = 4,
    keep_dc_gain: bool = True,
    n_freq: int = 300,
    dense_factor: int = 4,
    seed: int = 0,
    mu_schedule=(100.0, 1e3, 1e4),
    max_steps: int = 300,
    validate_designs: bool = True,
    model_error_draws: bool = False,
    n_holdout_freq: int = 600,
    frf=None,
    evidence: bool = True,
    kappa: float = KAPPA,
    mismatch: float | None = None,
    evidence_ts: float | None = None,
    evidence_bandwidth: bool = False,
    draw_family: str = "params",
    progress=None,
    certified_fallback: bool = True,
) -> dict:
    """Tune g for ``model`` over posterior ``samples`` and/or ``device`` variants, then
    re-check start and tuned designs with the non-smooth analyses.

    With ``model_error_draws`` and samples that carry a model-error term (white or GP,
    :attr:`PosteriorSamples.error_kind`), the training and held-out plants are
    posterior-*predictive* draws (:func:`predictive_scenario_plants`; held out on
    ``n_holdout_freq`` points of :func:`posterior_grid`), not the bare second-order models.
    Off by default: above the fit band the predictive plants are the second-order model (the
    data say nothing there), so a design tuned on them alone is blind to phase lag there; with
    the evidence constraints (on by default) it is certified but at a lower bandwidth than the
    loop draws give (docs/robust-design.md, Evidence E11).

    ``evidence_bandwidth`` (off): let the measured FRF claim the bandwidth instead of the
    median draw. Off by default: it relies on draws wide enough to cover the plant between
    the measured frequencies, where the measured loci say nothing (docs/robust-design.md,
    Evidence E11).

    ``draw_family="loop_gp"``: the training and held-out plants are draws of the loop
    coordinate ``Q = P P̂⁻¹`` itself, conditioned on the whole measured FRF
    (:mod:`hapid.uncertainty._loopgp`: a GP of ``Q − I`` in ln ω, hyperparameters by leave-one-out;
    ``frf`` required, ``samples`` not used) instead of posterior draws of the second-order
    fit. Calibrated in loop coordinates where the parameter draws are not
    (docs/robust-design.md, Evidence E3).

    **Chance constraint.** The margins on the posterior draws must hold on ``quantile``
    (0.975) of the ``n_train`` (150) training draws: a CVaR of the smooth disc constraint in
    which draws whose closed loop is unstable at the stage start are left out and counted as
    violators (:func:`hapid.tune._objective.masked_cvar`,
    :func:`hapid.tune._tune.stable_scenarios`); held-out draws check it.

    **Evidence-limited design (default, ``evidence=True``)**: with a measured FRF (``frf``:
    an :class:`~hapid.frf.FRF` or dict with ``omega, Z_H, Z_T``; else the fit data stored with
    the samples, :attr:`PosteriorSamples.predictive`) the tuner also (1) keeps the loci of the
    *measured* loop ``P_meas G`` out of the ``1/M_s`` disc around −1 at every measured
    frequency (family ``frf``) and (2) holds the loop small-gain beyond the highest measured
    frequency ω_e: ``|g(jω)| · m ≤ κ`` for ω ≥ ω_e, ``m`` a bound on the mismatch
    ``σ̄(P P̂⁻¹)`` there (default: its largest measured value in the top half-octave; pass
    ``mismatch`` to override) and ``κ`` = ``kappa`` (1/2). Then whatever the plant does above
    the data cannot change the Nyquist count of the loop, and a locus crossing −1's axis
    there has GM ≥ 1/κ (the argument: :mod:`hapid.tune._evidence`). With only the samples'
    fit data (40 Hz) as evidence, (2) acts from 40 Hz and costs bandwidth: give the whole
    measured FRF (``hapid tune --frf``) to use all the evidence.

    **Between the grid points.** The margin constraints are imposed on ``n_freq`` points; a
    lightly damped mode between two of them is invisible to the tuner. With ``dense_factor``
    > 1 (default 4) the device variants and the posterior models are also evaluated on
    ``dense_factor · n_freq`` points, and after each stage the tuner adds the dense
    frequencies where the margin constraint is violated to its grid and repeats the stage
    (:mod:`hapid.tune._exchange`; why: docs/robust-design.md, Evidence E7).

    **Never worse than the start.** With validation on, the tuned g is kept only if, on the
    held-out evidence (posterior draws; device variants and the nominal true plant when a
    device is given), it is no worse than the start: the fraction of plants meeting the
    margins does not drop, and it rises or (equal) the median isotropic bandwidth rises (and
    a stable true plant stays stable). Otherwise ``out["kept_start"]`` is True, the
    result's ``g`` is the start and ``out["decision"]`` says why. **Certified fallback**
    (``certified_fallback``, default on, with evidence): when the design so chosen is not
    certified by the evidence, the start and the tuned g are each scaled in gain to the
    largest value the evidence certifies (:func:`certified_gain`), re-checked, and the
    better returned (``out["table"]["returned"]``; why: docs/robust-design.md, Evidence E7).

    Returns ``{"result": TuneResult, "candidate": TuneResult (the tuner's g even when the
    start was kept), "families": {...sizes}, "validation": {"start": v,
    "tuned": v}, "table": {"start": row, "tuned": row}, "kept_start": bool, "decision": str}``
    (``v`` from :func:`.validate`, ``row`` from :func:`.table_row`).
    """

    if draw_family not in ("params", "loop_gp"):
        raise ValueError(
            f"robust_design: draw_family must be 'params' or 'loop_gp', got {draw_family!r}"
        )
    if draw_family == "loop_gp":
        src = frf if frf is not None else getattr(samples, "predictive", None)
        if src is None:
            raise ValueError("robust_design: draw_family='loop_gp' needs a measured FRF (frf=…)")
    elif samples is None and device is None:
        raise ValueError("robust_design: give posterior samples, a device, or both")
    g0 = Compensator.paper() if g0 is None else g0
    if evidence_ts is None and device is not None:  # the loop the device closes: its rate
        evidence_ts = float(device.ts)
    req = Requirements() if requirements is None else requirements
    if keep_dc_gain and req.min_dc_gain is None:
        # static accuracy no worse than the start's: |g(0)| ≥ |g0(0)|
        req = dataclasses.replace(req, min_dc_gain=float(np.abs(g0(np.array([0.0]))[0])))
    rng = np.random.default_rng(seed)
    note(progress, "building the training plants")
    families, info = [], {}
    hold_models = None
    omc = posterior_grid(n_freq)
    if draw_family == "loop_gp":
        lgp = measured_loop_gp(measured_data(src), model)
        fam, hold_models, om_h = loop_draw_family(
            lgp, model, n_freq=n_freq, dense_factor=dense_factor, n_train=n_train,
            n_holdout=n_holdout, n_holdout_freq=n_holdout_freq, quantile=quantile,
            bandwidth=posterior_bandwidth, seed=seed, ts=evidence_ts,
        )  # fmt: skip
        families.append(fam)
        info["posterior"] = {"train": int(n_train), "held_out": int(n_holdout),
                             "plants": "loop GP (Q = P P̂⁻¹ conditioned on the measured FRF)",
                             "loop_gp": {"ell": lgp.ell, "eta": lgp.eta, "sigma2": lgp.sigma2}}  # fmt: skip
    elif samples is not None:
        S = _n_models(samples)
        if S < 2:
            raise ValueError("robust_design: need at least 2 posterior samples (train + held out)")
        perm = rng.permutation(S)
        k = min(n_train, S // 2)
        tr, ho = perm[:k], perm[k : k + n_holdout]
        pred = model_error_draws and _has_error_term(samples)
        if pred:
            P, pol = predictive_scenario_plants(samples, tr, omc, seed=seed)
            hold_models = predictive_scenario_plants(
                samples, ho, posterior_grid(n_holdout_freq), seed=seed + 1
            )[0]
        else:
            P, pol = posterior_plants(_sample_models(samples, tr), omc)
            hold_models = _sample_models(samples, ho)
        dense = None
        if dense_factor > 1 and not pred:
            omc_d = posterior_grid(dense_factor * n_freq)
            P_d, pol_d = posterior_plants(_sample_models(samples, tr), omc_d)
            dense = make_scenarios(P_d, model, omc_d, p_ol=pol_d)
        families.append(Family(make_scenarios(P, model, omc, p_ol=pol), quantile=quantile,
                               bandwidth=posterior_bandwidth, bw_quantile=0.5, name="posterior",
                               dense=dense))  # fmt: skip
        info["posterior"] = {"train": int(k), "held_out": int(len(ho)),
                             "plants": f"predictive ({samples.error_kind} model error)" if pred else "models"}  # fmt: skip
    variants = None
    if device is not None:
        omd = below_nyquist_grid(device.fs_hz, n_freq)
        poses = [device.pose.moved(*o) for o in TRAIN_OFFSETS]
        labels, P = device_plants(device, omd, poses=poses, n_subjects=n_subjects, key=seed + 1,
                                  include_nominal=False)  # fmt: skip
        dense = None
        if dense_factor > 1:
            omd_d = count_grid(device.fs_hz, dense_factor, n_freq)
            # in chunks of the training grid's size: the compiled plant program is reused
            P_d = []
            for chunk in omd_d.reshape(-1, n_freq):
                labels_d, P_c = device_plants(device, chunk, poses=poses, n_subjects=n_subjects,
                                              key=seed + 1, include_nominal=False)  # fmt: skip
                if list(labels_d) != list(labels):
                    raise RuntimeError(
                        "robust_design: dense device variants differ from the training ones"
                    )
                P_d.append(np.asarray(P_c))
            P_d = np.concatenate(P_d, axis=1)
            dense = make_scenarios(P_d, model, omd_d, ts=device.ts, labels=labels)
        families.append(Family(make_scenarios(P, model, omd, ts=device.ts, labels=labels), quantile=1.0,
                               bw_quantile=0.5, name="device", dense=dense))  # fmt: skip
        info["device"] = {"train": len(labels)}
        if validate_designs:
            omv = device_grid(device.fs_hz)
            hp = [device.pose.moved(*o) for o in HOLDOUT_OFFSETS]
            variants = device_plants(device, omv, poses=hp, n_subjects=n_holdout_subjects, key=seed + 1000,
                                     include_nominal=False)  # fmt: skip
            info["device"]["held_out"] = len(variants[0])
    if device is None:
        families[0] = dataclasses.replace(families[0], quantile=quantile, bandwidth=True,
                                          bw_quantile=0.5)  # fmt: skip
    # the box of g's frequencies as without the evidence family (whose grid ends at ω_e)
    f_max_hz = (
        0.45 * device.fs_hz
        if device is not None
        else float(posterior_grid(n_freq)[-1]) / TWO_PI / 4.0
    )
    ev = None
    if evidence:
        src = frf if frf is not None else getattr(samples, "predictive", None)
        if src is not None:
            ev = evidence_from_frf(src, model, mismatch=mismatch, kappa=kappa, ts=evidence_ts,
                                   source="frf" if frf is not None else "samples' fit data")  # fmt: skip
            families.append(Family(make_scenarios(ev.P, model, ev.omega, ts=ev.ts), quantile=1.0,
                                   bandwidth=evidence_bandwidth, name="frf", contour=False))  # fmt: skip
            if evidence_bandwidth and device is None and not posterior_bandwidth:
                # the measured plant claims the bandwidth; the draws keep the margins
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
    train_req = req  # sampled plants: train with the PM allowance, re-check without it
    if any(f.quantile < 1.0 for f in families):
        train_req = dataclasses.replace(req, pm_deg=req.pm_deg + TUNE_PM_ALLOWANCE_DEG)
    res = tune(families, g0, requirements=train_req, mu_schedule=mu_schedule,
               max_steps=max_steps, f_max_hz=f_max_hz, progress=progress)  # fmt: skip
    out = {"result": res, "candidate": res, "families": info, "kept_start": False,
           "decision": "not validated"}  # fmt: skip
    # never worse than the start on the training loops' stability (the analysis' rule)
    ok_tr, why_tr = training_no_worse(res)
    if not ok_tr:
        out.update(kept_start=True, decision=why_tr,
                   result=dataclasses.replace(res, g=g0, x=res.x0, training=res.training0))  # fmt: skip
        if not validate_designs:
            return out
    if validate_designs:
        out["validation"], out["table"] = {}, {}
        omega_c = (
            posterior_grid(n_holdout_freq)
            if isinstance(hold_models, np.ndarray)
            else posterior_grid()
        )
        hold_ts = None
        if draw_family == "loop_gp" and evidence_ts is not None:
            omega_c, hold_ts = om_h, evidence_ts
        for name, g in (("start", g0), ("tuned", res.g)):
            note(progress, f"re-checking the {name} g (held-out plants, true plant)")
            t0 = time.perf_counter()
            v = validate(g, model, samples=hold_models, device=device, variants=variants,
                         omega_c=omega_c, gm_db=req.gm_db, pm_deg=req.pm_deg,
                         p_required=quantile, ts=hold_ts)  # fmt: skip
            out["validation"][name] = v
            out["table"][name] = table_row(v) | {"validate_s": time.perf_counter() - t0}
        ev_chk = ev
        if ev_chk is None and frf is not None:
            ev_chk = evidence_from_frf(frf, model, mismatch=mismatch, kappa=kappa, ts=evidence_ts)
        if ev_chk is None and getattr(samples, "predictive", None) is not None:
            ev_chk = evidence_from_frf(samples.predictive, model, mismatch=mismatch, kappa=kappa,
                                       ts=evidence_ts)  # fmt: skip
        if ev_chk is not None:
            for name, g in (("start", g0), ("tuned", res.g)):
                out["table"][name] |= certificate(ev_chk, model, g, floor=FRF_FLOOR)
        better, why = no_worse(out["table"]["start"], out["table"]["tuned"])
        out["decision"] = why if ok_tr else why_tr
        if not (better and ok_tr):
            out["kept_start"] = True
            out["result"] = dataclasses.replace(res, g=g0, x=res.x0)
        chosen = out["table"]["start" if out["kept_start"] else "tuned"]
        if (
            ev_chk is not None
            and certified_fallback
            and not (chosen.get("certified", True) and _meets_chance(chosen, quantile))
        ):
            note(progress, "not certified: trying the certified-gain fallback")
            fb = _certified_fallback(out, g0, res, ev_chk, model, hold_models, device, variants,
                                     omega_c, req, quantile, with_tuned=ok_tr, chosen=chosen, ts=hold_ts)  # fmt: skip
            if fb is not None:
                out["result"], out["table"]["returned"], out["decision"] = fb
                out["kept_start"] = False
        row = (
            out["table"].get("returned") or out["table"]["start" if out["kept_start"] else "tuned"]
        )
        ck = design_check(row, gm_db=req.gm_db, pm_deg=req.pm_deg, quantile=quantile,
                          ts=evidence_ts, g_max=None if ev_chk is None else ev_chk.g_max)  # fmt: skip
        out["result"] = dataclasses.replace(out["result"], check=ck)
        out["check"], out["loop"] = ck, loop_label(evidence_ts)
    return out
