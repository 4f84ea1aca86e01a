"""The end-to-end recipe behind ``hapid tune``: build scenario families, tune, re-check.

Families (see :class:`.Family`):

* ``posterior`` — ``n_train`` posterior samples (continuous loops ``P̂_s · g Ẑ_T Ẑ_H⁻¹``).
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

import jax
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from .._grids import NYQUIST_F_MIN_HZ, below_nyquist_grid, log_grid_hz, nyquist_grid
from .._grids import continuous_grid as posterior_grid
from ..control import Compensator
from ._check import FRF_FLOOR, design_check, loop_label
from ._evidence import KAPPA, beyond_grid, certificate, evidence_from_frf, measured_plant
from ._objective import Family, Requirements
from ._params import ParamMap
from ._progress import note
from ._scenarios import make_scenarios
from ._tune import largest_gain, scale_gain, tune
from ._validate import device_grid, table_row, validate

TRAIN_OFFSETS = (
    (0.04, 0, 0),
    (-0.04, 0, 0),
    (0, 0.04, 0),
    (0, -0.04, 0),
    (0, 0, 0.04),
    (0, 0, -0.04),
)
PREDICTIVE_TAPER = 0.1  # ln-ω width of the model-error taper beyond the fit band
HOLDOUT_OFFSETS = ((0.03, 0.03, 0), (-0.03, -0.03, 0), (0.03, 0, 0.03), (0, -0.03, -0.03))


def _sample_models(samples, idx):
    from ..uncertainty import PosteriorSamples

    if isinstance(samples, PosteriorSamples):
        return samples.models(np.asarray(idx))
    return jax.tree.map(lambda a: a[np.asarray(idx)], samples)


def _n_models(samples) -> int:
    from ..uncertainty import PosteriorSamples

    return (
        samples.n_samples
        if isinstance(samples, PosteriorSamples)
        else int(np.shape(samples.hand.M)[0])
    )


def _subset(samples, idx):
    return dataclasses.replace(samples, samples=samples.samples[np.asarray(idx)],
                               log_prob=np.asarray(samples.log_prob)[np.asarray(idx)])  # fmt: skip


def _has_error_term(samples) -> bool:
    from ..uncertainty import PosteriorSamples

    return (isinstance(samples, PosteriorSamples) and samples.error_kind != "none"
            and samples.predictive is not None)  # fmt: skip


def predictive_scenario_plants(samples, idx, omega, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(P (S, N, n, n), RHP poles)``: posterior-*predictive* plants of draws ``idx`` on ω —
    the second-order model of each draw plus its model-error term
    (:func:`hapid.uncertainty.predictive_plants`), so the tuner and the re-check see the
    misfit the data show (delay, unmodeled modes) and not only parameter uncertainty. The
    error term is confined to the fit band (``error_band``, taper ``PREDICTIVE_TAPER`` in
    ln ω): outside it the data say nothing about the error, and the GP's extrapolation (its
    prior, ~τ_H ≈ 0.45 relative on cu5) is a random perturbation the data do not support
    that flips the Nyquist count of loops crossing over just above the band (measured on
    cu5, paper g, 40 draws, 2000-point grid: P(stable) 0.95 / 0.93 / 0.85 / 0.45 / 0.30 for
    taper widths 0.1 / 0.25 / 0.5 / 1 / 2); there the draw is its second-order model. The
    RHP poles are those of the draw's model (0 for PD matrices)."""
    from ..uncertainty import predictive_plants

    sub = _subset(samples, idx)
    om_fit = np.asarray(samples.predictive["omega"])
    P = predictive_plants(
        sub,
        omega,
        max_samples=None,
        seed=seed,
        error_band=(om_fit[0], om_fit[-1]),
        taper_width=PREDICTIVE_TAPER,
    )["P"]
    _, pol = posterior_plants(sub.models(), omega)
    return P, pol


def posterior_plants(models, omega) -> tuple[np.ndarray, np.ndarray]:
    """``(P (S, N, n, n), RHP poles of each P̂_s)`` of a batched model on ω (rad/s)."""

    @jax.jit
    def one(m):
        r = m.total.roots()
        return m.P(1j * omega), np.int64(0) + jax.numpy.sum(jax.numpy.real(r) > 0)

    P, n = jax.vmap(one)(models)
    return np.asarray(P), np.asarray(n)


def count_grid(fs_hz: float, dense_factor: int, n_freq: int) -> np.ndarray:
    """The device family's dense grid (rad/s, sorted, ``(dense_factor + 1) · n_freq``
    points): :func:`below_nyquist_grid` with ``dense_factor · n_freq`` points (0.1 Hz to
    0.499 f_s), a low tail from the analysis grid's 10⁻³ Hz up to 0.1 Hz and the Nyquist
    frequency itself — so that its Nyquist count closes at both ends as the analysis'
    (:func:`hapid._grids.nyquist_grid`) does: measured on cu5 with 3 samples of delay,
    ``det(I + L)`` is at −90° at 0.1 Hz."""
    band = below_nyquist_grid(fs_hz, dense_factor * n_freq)
    tail = log_grid_hz(NYQUIST_F_MIN_HZ, 0.1, n_freq)[:-1]
    return np.sort(np.concatenate([tail, band, [np.pi * float(fs_hz)]]))


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
    draw_family: str = "samples",
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
    loop draws give (docs/robust-design.md, section `draw_family="loop_gp"`).

    ``evidence_bandwidth`` (off): let the measured FRF claim the bandwidth instead of the
    median draw. With narrow NLS-Laplace draws (24, q = 0.95) it failed on cu5: 6.9 Hz on the
    true plant but GM −2.0 dB, PM 8.8° — the loci met the disc at the 28 measured
    frequencies and passed near −1 between them. With the chance constraint on gp draws
    (125 trained on, q = 0.975) the draws guard the margins between the measured points:
    cu5 2.41 Hz, GM 6.9 dB, PM 54° (median-draw bandwidth: 1.19 Hz); tripod3 2.77 Hz, GM
    7.6 dB, PM 44° (2.42 Hz) — all certified (docs/robust-design.md). Off by default: it relies on draws
    wide enough to cover the plant between the measured frequencies.

    ``draw_family="loop_gp"``: the training and held-out plants are draws of the loop
    coordinate ``Q = P P̂⁻¹`` itself, conditioned on the whole measured FRF
    (:mod:`hapid.uncertainty._loopgp`: a GP of ``Q − I`` in ln ω, hyperparameters by leave-one-out;
    ``frf`` required, ``samples`` not used) instead of posterior draws of the second-order
    fit. Calibrated in loop coordinates on cu5 and tripod3 + 2 ms where the gp posterior's
    draws are not (benchmarks/calibrate_loop.py, docs/robust-design.md).

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
    (:mod:`hapid.tune._exchange`). Measured on the paper scene (cu5): a design whose loci met
    the disc at all 300 training points had GM 2.0 dB on every training variant on the
    analysis grid (a chain mode at 171 Hz between two points).

    **Never worse than the start.** With validation on, the tuned g is kept only if, on the
    held-out evidence (posterior draws; device variants and the nominal true plant when a
    device is given), it is no worse than the start: the fraction of plants meeting the
    margins does not drop, and it rises or (equal) the median isotropic bandwidth rises (and
    a stable true plant stays stable). Otherwise ``out["kept_start"]`` is True, the
    result's ``g`` is the start and ``out["decision"]`` says why. **Certified fallback**
    (``certified_fallback``, default on, with evidence): when the design so chosen is not
    certified by the evidence, the start and the tuned g are each scaled in gain to the
    largest value the evidence certifies (:func:`certified_gain`), re-checked, and the
    better returned (``out["table"]["returned"]``). Measured on a held-out tripod3 variant
    (4 samples of delay, compliant rods, moved stylus; paper protocol): neither was certified,
    the tuned g was kept on better figures and was unstable on the true plant (a locus
    around −1 between the measured 40 and 45 Hz); the paper g at 0.35 of its gain is
    certified and stable there (GM 7.9 dB, PM 50°, 1.45 Hz).

    Returns ``{"result": TuneResult, "candidate": TuneResult (the tuner's g even when the
    start was kept), "families": {...sizes}, "validation": {"start": v,
    "tuned": v}, "table": {"start": row, "tuned": row}, "kept_start": bool, "decision": str}``
    (``v`` from :func:`.validate`, ``row`` from :func:`.table_row`).
    """
    from ..uncertainty import device_plants

    if draw_family not in ("samples", "loop_gp"):
        raise ValueError(
            f"robust_design: draw_family must be 'samples' or 'loop_gp', got {draw_family!r}"
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
        from ..uncertainty._loopgp import fit_loop_gp, loop_gp_plants, measured_data

        d = measured_data(src)
        lgp = fit_loop_gp(
            np.asarray(d["omega"], dtype=float), measured_plant(d["Z_H"], d["Z_T"]), model
        )
        dense = None
        if dense_factor > 1:  # the same draws on the dense grid (one joint GP draw)
            omc_d = posterior_grid(dense_factor * n_freq)
            P_all = loop_gp_plants(lgp, model, np.concatenate([omc, omc_d]), n_train, seed)
            P, P_d = P_all[:, : omc.size], P_all[:, omc.size :]
            dense = make_scenarios(P_d, model, omc_d)
        else:
            P = loop_gp_plants(lgp, model, omc, n_train, seed)
        # held out at the controller's rate (the discretized controller on a grid to fs/2)
        om_h = (posterior_grid(n_holdout_freq) if evidence_ts is None
                else nyquist_grid(1.0 / evidence_ts, n_holdout_freq))  # fmt: skip
        hold_models = loop_gp_plants(lgp, model, om_h, n_holdout, seed + 1)
        families.append(Family(make_scenarios(P, model, omc), quantile=quantile,
                               bandwidth=posterior_bandwidth, bw_quantile=0.5, name="posterior",
                               dense=dense))  # fmt: skip
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
    f_max_hz = 0.45 * device.fs_hz if device is not None else float(omc[-1]) / TWO_PI / 4.0
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
    res = tune(families, g0, requirements=req, mu_schedule=mu_schedule, max_steps=max_steps,
               f_max_hz=f_max_hz, progress=progress)  # fmt: skip
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


def certified_gain(
    g: Compensator, ev, model, floor: float = 0.5, alpha_min: float = 1e-3, iters: int = 14
) -> float | None:
    """Largest ``α ≤ 1`` (bisection in log α) at which ``g`` with its gain ``k`` scaled by
    ``α`` is certified by the evidence (:func:`._evidence.certificate`: nominal loop stable,
    measured loci ``min |1 + λ| ≥ floor``, loop gain beyond the FRF ≤ κ); ``None`` if not even
    ``alpha_min`` is. Lower gain shrinks the loop everywhere, so the certificate's figures
    improve monotonically in practice (not assumed: the bisection keeps the last certified α)."""
    certified = lambda gg: certificate(ev, model, gg, floor=floor)["certified"]  # noqa: E731
    if certified(g):
        return 1.0
    return largest_gain(g, certified, alpha_min, iters)


def _certified_fallback(out, g0, res, ev, model, hold_models, device, variants, omega_c, req,
                        quantile, *, with_tuned: bool = True, chosen: dict | None = None,
                        ts: float | None = None):  # fmt: skip
    """The chosen design is not certified by the evidence, or fails the held-out draws'
    chance level (``quantile`` of them meeting the margins): the start and the tuned g, each
    with its gain scaled down to the largest value the evidence certifies
    (:func:`certified_gain`), re-checked like the others. A candidate certified *and* at the
    chance level is preferred (the better of two by :func:`no_worse`); when none is, a
    certified ``chosen`` design is kept (``None``: lowering the gain trades one failed
    figure for another — it can move the crossover below the lowest measured frequency,
    where the certificate sees nothing), else the better certified candidate is returned.
    The tuned g only with ``with_tuned`` (it passed :func:`training_no_worse`); a candidate
    that makes the nominal true plant unstable where the ``chosen`` design's row has it
    stable is dropped. ``ts``: the held-out draws' controller rate (:func:`.validate`).
    ``(result, row, decision)`` or ``None``."""
    cands = []
    pairs = (("start", g0), ("tuned", out["candidate"].g)) if with_tuned else (("start", g0),)
    for name, g in pairs:
        a = certified_gain(g, ev, model, floor=FRF_FLOOR)
        if a is None:
            continue
        gs = scale_gain(g, a)
        v = validate(gs, model, samples=hold_models, device=device, variants=variants,
                     omega_c=omega_c, gm_db=req.gm_db, pm_deg=req.pm_deg, p_required=quantile,
                     ts=ts)  # fmt: skip
        row = table_row(v) | certificate(ev, model, gs, floor=FRF_FLOOR)
        if (chosen or {}).get("true_stable") and not row.get("true_stable", True):
            continue
        cands.append((name, a, gs, row))
    best = pick_fallback(cands, chosen, quantile)
    if best is None:
        return None
    name, a, gs, row = best
    pm = ParamMap.from_template(gs)
    head = ("neither the start nor the tuned g is certified by the evidence"
            if not (chosen or {}).get("certified", False)
            else "the chosen g fails the held-out draws' chance level")  # fmt: skip
    why = (f"{head}: returned the "
           f"{name} g with its gain scaled by {a:.3g}, the largest the evidence certifies "
           f"(measured min |1 + λ| {row['frf_min_loci_distance']:.3g}, loop gain beyond "
           f"{row['evidence_hz']:.3g} Hz {row['beyond_loop_gain']:.3g})")  # fmt: skip
    return dataclasses.replace(res, g=gs, x=np.asarray(pm.vector(gs))), row, why


def pick_fallback(cands: list, chosen: dict | None, quantile: float):
    """The fallback's choice among certified candidates ``(name, α, g, row)`` (rows of
    :func:`.table_row` plus the certificate): those whose held-out draws meet the margins at
    the chance level first (of two, the later one when :func:`no_worse` prefers it); none
    such and a certified ``chosen`` row: ``None`` (keep it); else the better of all."""
    good = [c for c in cands if _meets_chance(c[3], quantile)]
    if not good and (chosen or {}).get("certified", False):
        return None
    cands = good or cands
    if not cands:
        return None
    if len(cands) == 2 and no_worse(cands[0][3], cands[1][3])[0]:
        return cands[1]
    return cands[0]


def _meets_chance(row: dict, quantile: float) -> bool:
    """Do the held-out posterior draws of a :func:`.table_row` meet the margins at the
    chance level (True when the row has no posterior draws)?"""
    return row.get("posterior_frac_meeting_margins", 1.0) >= quantile - 1e-9


FRF_KEY = "frf_min_loci_distance"  # the measured-FRF figure rows are compared on (certificate)


def training_no_worse(res) -> tuple[bool, str]:
    """``(ok, why)``: is the tuned g (``res.training``) stable on at least as many training
    loops as the start (``res.training0``), and on all it must be wherever the start is?
    Counted by the analysis' Nyquist rule (:func:`hapid.tune.training_verdict`)."""
    tot = lambda d: sum(v[0] for v in d.values())  # noqa: E731
    enough = lambda d: all(v[0] >= v[1] for v in d.values())  # noqa: E731
    a, b = tot(res.training0), tot(res.training)
    if enough(res.training0) and not enough(res.training):
        return False, (f"kept the start: the tuned g leaves training loops unstable "
                       f"({b} stable against the start's {a})")  # fmt: skip
    if b < a:
        return False, f"kept the start: {b} stable training loops against the start's {a}"
    if not enough(res.training):
        return True, (f"no g found that is stable on the training loops ({b} stable, start "
                      f"{a}): not a valid design")  # fmt: skip
    return True, "stable on the training loops"


def no_worse(start: dict, tuned: dict) -> tuple[bool, str]:
    """Is the tuned design no worse than the start on the held-out evidence of two
    :func:`.table_row` rows? ``(verdict, one-line reason)``. Evidence, in order: the nominal
    true plant stays stable (when present); for each family (posterior, variants) the
    fraction of plants meeting the margins does not drop, and it either rises or, equal, the
    median isotropic bandwidth rises — a tuned g that improves nothing is not returned. With
    ``frf_min_loci_distance`` in both rows (:func:`._evidence.certificate`, the measured FRF)
    the tuned g may not bring the loop on the data closer to −1 than the start when it falls
    below ``FRF_FLOOR``. With ``certified`` in both rows (:func:`._evidence.certificate`:
    evidence) the evidence decides first: a certified start is never traded for an
    uncertified g, and a certified tuned g replaces an uncertified start. When *neither* is
    certified, both are judged on the same evidence figures: the tuned g must be no worse on
    each (stable on the model's own plant if the start is, measured return difference not
    lower, beyond-band gain bound not above ``max(start, κ)``) and then better on the held-out
    draws; otherwise the start is kept and the reason says which figure decided."""
    if start.get("true_stable") and not tuned.get("true_stable", True):
        return False, "kept the start: the tuned g makes the nominal true plant unstable"
    c = "certified"
    if c in start and c in tuned:
        if start[c] and not tuned[c]:
            return False, ("kept the start: it holds on the evidence (measured FRF, small gain "
                           "beyond it) and the tuned g does not")  # fmt: skip
        if tuned[c] and not start[c]:
            return True, ("tuned g kept: it holds on the evidence (measured FRF min |1 + λ| "
                          f"{tuned[FRF_KEY]:.3g}, loop gain beyond "
                          f"{tuned['evidence_hz']:.3g} Hz ≤ {tuned['beyond_loop_gain']:.3g}) and the "
                          f"start does not (min |1 + λ| {start[FRF_KEY]:.3g}, gain "
                          f"beyond {start['beyond_loop_gain']:.3g})")  # fmt: skip
        if not tuned[c]:  # neither certified: the tuned g must be no worse on each figure
            if start.get("nominal_stable", True) and not tuned.get("nominal_stable", True):
                return False, ("kept the start: neither is certified, and the tuned g is not stable "
                               "on the model's own plant while the start is")  # fmt: skip
            if tuned["beyond_loop_gain"] > max(start["beyond_loop_gain"], KAPPA) + 1e-9:
                return False, (f"kept the start: neither is certified, and beyond the evidence "
                               f"({tuned['evidence_hz']:.3g} Hz) the tuned loop gain bound "
                               f"{tuned['beyond_loop_gain']:.3g} exceeds the start's "
                               f"{start['beyond_loop_gain']:.3g}")  # fmt: skip
            k = FRF_KEY
            if tuned[k] < start[k] - 1e-9:
                return False, (f"kept the start: neither is certified, and on the measured FRF the "
                               f"tuned loop comes closer to −1 (min |1 + λ| {tuned[k]:.3g} against "
                               f"{start[k]:.3g})")  # fmt: skip
    k = FRF_KEY
    if k in start and k in tuned and tuned[k] < min(start[k], FRF_FLOOR) - 1e-9:
        return False, (f"kept the start: on the data's own FRF the tuned g brings the loop closer to "
                       f"−1 (min |1 + λ| {tuned[k]:.3g} against {start[k]:.3g} for the start)")  # fmt: skip
    gains = []
    for fam in ("posterior", "variants"):
        key = f"{fam}_frac_meeting_margins"
        if key not in start:
            continue
        a, b = start[key], tuned[key]
        if b < a - 1e-9:
            return False, (f"kept the start: on held-out {fam} plants the tuned g meets the margins "
                           f"on {100 * b:.1f} % against {100 * a:.1f} % for the start")  # fmt: skip
        bw_a, bw_b = start[f"{fam}_iso_bandwidth_hz_q50"], tuned[f"{fam}_iso_bandwidth_hz_q50"]
        if b <= a + 1e-9 and not bw_b > bw_a + 1e-6:
            return False, (f"kept the start: no improvement on held-out {fam} plants (margins met on "
                           f"{100 * b:.1f} % vs {100 * a:.1f} %, median bandwidth {bw_b:.3g} vs "
                           f"{bw_a:.3g} Hz)")  # fmt: skip
        gains.append(f"{fam}: margins met {100 * a:.1f} → {100 * b:.1f} %, median bandwidth "
                     f"{bw_a:.3g} → {bw_b:.3g} Hz")  # fmt: skip
    if not gains:
        return True, "no held-out evidence to compare on: tuned g returned unchecked"
    return True, "tuned g kept (no worse than the start on held-out plants): " + "; ".join(gains)
