"""Calibration of the posterior-predictive band of P, Z_H, Z_T on misspecified devices.

For each device: simulate the paper's multisine experiments (periodic steady state, default
protocol), estimate the FRF, fit the NLS model (relative weights, ≤ 40 Hz), build the
posterior with each model error (white; gp: independent GPs of the Z_H and Z_M misfits;
gp_corr: correlated through a shared latent GP, asinh knee coordinate, marginal
hyperparameters — docs/conventions.md "Posterior"), draw the predictive plant on a dense grid
of 1–40 Hz *excluding* the experiment frequencies (held out: ≥ 5 % away from any of them)
and compare with the device's true sampled response there
(:func:`hapid.uncertainty.band_calibration`: coverage of the 90 % credible ball around the
draws' median, its median radius over the median actual error, per-element re/im interval
coverage). Devices:

- ``cu5`` — the development device (two-layer hand, compliant chain, 1-sample delay);
- ``tripod3_d2`` — the second misspecified device, chosen *before* any tuning and never
  used to tune the likelihood: a 3-rod tripod with a 2-sample (2 ms) actuator delay;
- ``hexapod6_d2`` — the held-out check, chosen before it was ever run and reported once: a
  6-rod hexapod with a 2-sample delay (one more than its preset);
- the **held-out family of the draw constructions** (``params``: the posterior's parameter
  draws plus its model-error term; ``loop_gp``: draws of ``Q = P P̂⁻¹`` conditioned on the
  whole measured FRF, :func:`hapid.uncertainty.plant_draws`), fixed before either was run
  on it and run once per construction, no re-tuning: ``cu5_soft`` (the preset),
  ``cu5_d2`` (cu5, 2-sample delay), ``tripod3_c3`` (tripod3, rod compliance ×3, the CLI's
  ``--rod-compliance 3``), ``hexapod6_d2`` (above), ``quad4`` (the preset). ``cu5`` and
  ``tripod3`` at their defaults were development devices of the loop draws and do not count;
- the **second held-out family** (``--family second``; written 2026-12-05 before any run of
  it, after the first family's table was seen, to check both ``hapid posterior`` methods on
  devices that chose nothing): ``tripod3:delay=1:compliance=2``, ``quad4:delay=2``,
  ``cu5:delay=2:compliance=2``, ``hexapod6:compliance=2`` (``preset[:delay=S][:compliance=F]``,
  delay in samples, the chain-compliance factor: ``calibrate_robust.parse_device``). The cu5
  variant turned out to be the cu5_soft preset again, so three of the four devices are new;
- the **third held-out family** (``--family third``; written 2026-12-05 before any run of
  it, after both earlier tables and the seed spread of hexapod6_d2 were seen): 1–3 samples
  of delay, a moved stylus, 3 to 6 rods, and a 6-rod device with *more* delay than
  hexapod6_d2 (a harder case of the one device whose band is too wide):
  ``tripod3:delay=3``, ``quad4:delay=1:compliance=2``, ``cu5:delay=3:move=0,0,0.01``,
  ``hexapod6:delay=3``, ``hexapod6:move=0.01,0,0`` (the preset's own 1-sample delay);
- the **fourth held-out family** (``--family fourth``; written 2026-12-07 before any run of
  it, to judge the leave-one-frequency-out check of ``hapid predict`` whose threshold was
  chosen on the first three families): three 6-rod devices — where the band was found too
  narrow at 16–40 Hz — and three 3–5-rod ones, none used before by this script:
  ``tripod3:compliance=2:move=0,0.01,0``, ``quad4:delay=3``, ``cu5:delay=1:compliance=3``,
  ``hexapod6:delay=1:compliance=3``, ``hexapod6:move=0,0.01,0``,
  ``hexapod6:delay=2:move=0,0,0.01``; seeds 0, 1, 2;
- the **fifth held-out family** (``--family fifth``; written 2026-12-07 before any run of it,
  to judge a band widened by the leave-one-frequency-out check; the widening failed on the
  first four families and was dropped before this family ran, which then judged the check
  itself): ``tripod3:delay=2:move=0.01,0,0``, ``quad4:compliance=3``,
  ``cu5:delay=2:move=0,0.01,0``, ``hexapod6:delay=2:compliance=2``,
  ``hexapod6:compliance=3:move=0.01,0,0``, ``hexapod6:delay=3:move=0,0.01,0``; seeds 0, 1, 2;
- the **sixth held-out family** (``--family sixth``; written 2026-12-07 before any run of it,
  to judge the recalibrated band (``hapid.uncertainty.recalibrate``), whose four constants
  (an added term of half the left-out excess error, shrinking by at most half, a kernel of
  0.3 in ln f, 2 pseudo-observations at 1) were chosen on the fourth and fifth families):
  ``tripod3:delay=1:move=0,0,0.01``, ``quad4:delay=2:compliance=2``,
  ``cu5:compliance=2:move=0.01,0,0``, ``hexapod6:compliance=2:move=0,0,0.01``,
  ``hexapod6:delay=2:move=0.01,0,0``, ``hexapod6:delay=3:compliance=2``; seeds 0, 1, 2;
- the **seventh held-out family** (``--family seventh``; written 2026-12-07 before any run
  of it, after the sixth and the first three judged the recalibration, to judge the gap
  shape added to its added term then (``hapid.uncertainty._recalibrate.gap_shape``):
  ``tripod3:compliance=3:move=0.01,0,0``, ``quad4:delay=1:move=0,0,0.01``,
  ``cu5:delay=3:compliance=2``, ``hexapod6:delay=2:compliance=3``,
  ``hexapod6:compliance=2:move=0,0.01,0``, ``hexapod6:delay=3:move=0.01,0,0``; seeds 0, 1, 2;
- ``second_order`` — a strictly second-order n = 2 device. Its *measured* response is the
  sampled one (ZOH): Z_T carries a half-sample lag (~ωT/2) the continuous model lacks, and
  with force noise only the FRF's ``Z_T_std`` is 0 while the encoder quantization (2 µm)
  biases Z_H and Z_T by more than their std (not in it). So for Z_T this is a noise-free
  interpolation of a small misfit, not a model-class-right case;
- ``second_order_exact`` — the same device with a band-limited actuator (the FRF is the
  continuous response), encoder noise 2 µm and no quantization: the model class is exactly
  right and the std describes the whole data error (the nominal case for Z_H and Z_T too).

Metrics (:func:`hapid.uncertainty.band_calibration`): ``coverage`` — fraction of held-out
frequencies where the true P lies inside the 90 % credible ball (Frobenius norm) around the
draws' median; ``width / error`` — median over those frequencies of the ball's radius
(half-width) divided by the actual error ‖P_true − P̃‖_F at the same frequency; ``calibrated``
— the same ratio with one of the draws standing in for the truth (what this band would give
if it were exactly calibrated; a Gaussian gives 1.13–2.44 depending on its shape). ``eval ms``
is one log-posterior evaluation of 200 walkers (jitted, vmapped).

Kinds: the posterior's model error (``white``, ``gp``, ``gp_corr``, …: parameter draws
plus that model-error term, ``hapid predict --draws params``) and ``loop_gp`` (the loop draws
of ``hapid predict --draws loop_gp``, around the same NLS fit, from the same FRF; their
posterior is not used, so the row's posterior columns are empty).

Run:  PYTHONPATH=. python benchmarks/calibrate_predictive.py [--method laplace|emcee]
      [--draws 400] [--devices cu5,tripod3_d2,second_order,second_order_exact]
      [--kinds white,gp,gp_corr,gp_corr_el,gp_corr_cls,loop_gp]
Held-out family (both constructions):
      PYTHONPATH=. python benchmarks/calibrate_predictive.py --draws 200 --kinds gp_corr,loop_gp
      --devices cu5_soft,cu5_d2,tripod3_c3,hexapod6_d2,quad4 --quantities P
Spread over noise realizations: ``--seeds 0,1,2,3,4,5`` (one row per seed; the seed sets the
experiment's noise, the Laplace/emcee draws and the predictive draws). Where in frequency:
``--split-hz 16`` adds rows for the held-out frequencies below 16 Hz and at or above it.
``--recalibrate`` adds rows (``KIND recal.``) for the P band recalibrated on that check's
left-out errors (:func:`hapid.uncertainty.recalibration`, ``hapid predict``'s default).
``--holdout`` runs ``hapid predict``'s leave-one-frequency-out check and adds rows for the
held-out frequencies it leaves established (``est.``, and ``est. ≥16 Hz`` with ``--split-hz``)
and those it flags (``flagged``); a comment line per run names the flagged intervals.
Prints a markdown table.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import hapid
from hapid.device import SecondOrderDevice, preset
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.fit import fit_nls
from hapid.uncertainty import (
    PosteriorSamples,
    ShortChainWarning,
    band_calibration,
    batched_log_prob,
    boundary_fixed,
    holdout_check,
    initial_point,
    make_log_posterior,
    measured_data,
    model_error_from,
    param_names,
    plant_draws,
    posterior_laplace_samples,
    predictive_plants,
    recalibration,
    sample_posterior,
)

TWO_PI = 2.0 * np.pi

FAMILIES = {
    "first": ["cu5_soft", "cu5_d2", "tripod3_c3", "hexapod6_d2", "quad4"],
    "second": ["tripod3:delay=1:compliance=2", "quad4:delay=2", "cu5:delay=2:compliance=2",
               "hexapod6:compliance=2"],
    "third": ["tripod3:delay=3", "quad4:delay=1:compliance=2", "cu5:delay=3:move=0,0,0.01",
              "hexapod6:delay=3", "hexapod6:move=0.01,0,0"],
    "fourth": ["tripod3:compliance=2:move=0,0.01,0", "quad4:delay=3", "cu5:delay=1:compliance=3",
               "hexapod6:delay=1:compliance=3", "hexapod6:move=0,0.01,0",
               "hexapod6:delay=2:move=0,0,0.01"],
    "fifth": ["tripod3:delay=2:move=0.01,0,0", "quad4:compliance=3", "cu5:delay=2:move=0,0.01,0",
              "hexapod6:delay=2:compliance=2", "hexapod6:compliance=3:move=0.01,0,0",
              "hexapod6:delay=3:move=0,0.01,0"],
    "sixth": ["tripod3:delay=1:move=0,0,0.01", "quad4:delay=2:compliance=2",
              "cu5:compliance=2:move=0.01,0,0", "hexapod6:compliance=2:move=0,0,0.01",
              "hexapod6:delay=2:move=0.01,0,0", "hexapod6:delay=3:compliance=2"],
    "seventh": ["tripod3:compliance=3:move=0.01,0,0", "quad4:delay=1:move=0,0,0.01",
                "cu5:delay=3:compliance=2", "hexapod6:delay=2:compliance=3",
                "hexapod6:compliance=2:move=0,0.01,0", "hexapod6:delay=3:move=0.01,0,0"],
}  # fmt: skip
"""The held-out families of the module docstring (each written down before any run of it)."""


def _spd(rng, n, scale, cond=10.0):
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return Q @ np.diag(scale * np.geomspace(1.0 / cond, 1.0, n)) @ Q.T


def device(name: str):
    if ":" in name:  # preset[:delay=S][:compliance=F]: calibrate_robust.py's device specs
        from calibrate_robust import parse_device

        return parse_device(name)
    if name == "cu5":
        return preset("cu5")
    if name == "tripod3_d2":
        return preset("tripod3", delay_samples=2)
    if name == "hexapod6_d2":
        return preset("hexapod6", delay_samples=2)
    if name == "cu5_d2":
        return preset("cu5", delay_samples=2)
    if name == "tripod3_c3":
        return preset("tripod3", rod_compliance=3.0)
    if name in ("second_order", "second_order_exact"):
        rng = np.random.default_rng(0)
        hand = hapid.SecondOrder(_spd(rng, 2, 0.3), _spd(rng, 2, 10.0), _spd(rng, 2, 800.0))
        mech = hapid.SecondOrder(_spd(rng, 2, 0.6), _spd(rng, 2, 40.0), _spd(rng, 2, 200.0))
        return SecondOrderDevice(hand=hand, mechanism=mech, delay_samples=0)
    return preset(name)  # any other preset by name (e.g. cu5_soft); unknown names raise


def held_out_grid(freq_hz, f_lo=1.0, f_hi=40.0, n=200):
    f = np.geomspace(f_lo, f_hi, n)
    keep = np.min(np.abs(f[:, None] - np.asarray(freq_hz)[None]), axis=1) > 0.05 * f
    return TWO_PI * f[keep]


def truth(dev, omega, exact: bool = False):
    """The response the experiment measures: the *sampled* system (ZOH, 1 kHz), also for the
    second-order device (its continuous Z differs by the sampling: ~ωT/2 of phase); with
    ``exact`` (a band-limited actuator) the continuous response."""
    if exact:
        s = 1j * np.asarray(omega)
        ZH, ZT = (np.asarray(a) for a in dev.impedances(s))
        return {"Z_H": ZH, "Z_T": ZT, "P": np.asarray(dev.P(s))}
    ZH, ZT = (np.asarray(a) for a in dev.sampled_impedances(omega))
    return {"Z_H": ZH, "Z_T": ZT, "P": np.asarray(dev.sampled_P(omega))}


def split_figures(draws, truth, freq_hz, split_hz=None, check=None):
    """``[(band, figures, n)]``: :func:`~hapid.uncertainty.band_calibration`'s figures of the
    draws ``(S, N, n, n)`` against ``truth (N, n, n)`` over all ``N`` frequencies (``"all"``)
    and, with ``split_hz``, over the ``n`` below it and those at or above it (``freq_hz
    (N,)``): where in frequency a band is wide or short, which the median over all of them
    hides. With ``check`` (a :class:`~hapid.uncertainty.HoldoutCheck`) also over the
    frequencies it leaves established (``"est."``, ``"est. ≥F Hz"``) and those it flags
    (``"flagged"``)."""
    draws, truth, f = np.asarray(draws), np.asarray(truth), np.asarray(freq_hz)
    parts = [("all", np.ones(f.size, bool))]
    if split_hz is not None:
        parts += [(f"<{split_hz:g} Hz", f < split_hz), (f"≥{split_hz:g} Hz", f >= split_hz)]
    if check is not None:
        ok = check.covers(f)
        parts += [("est.", ok), ("flagged", ~ok)]
        if split_hz is not None:
            parts.append((f"est. ≥{split_hz:g} Hz", ok & (f >= split_hz)))
    return [(band, band_calibration(draws[:, m], truth[m]).figures(), int(m.sum()))
            for band, m in parts if m.any()]  # fmt: skip


def _eval_ms(post, x0, walkers=200, reps=20):
    f = batched_log_prob(post)
    X = post.project(x0 + 1e-4 * np.random.default_rng(0).standard_normal((walkers, x0.size)))
    f(X)
    t0 = time.perf_counter()
    for _ in range(reps):
        f(X)
    return (time.perf_counter() - t0) / reps * 1e3


def _loop_gp_rows(name, frf, nls, om, tr, draws, seed, quantities, split_hz=None):
    """The ``loop_gp`` construction: ``hapid predict --draws loop_gp``'s library call on a
    samples stand-in that carries the measured FRF and the NLS fit (no posterior needed)."""
    n = np.asarray(frf.Z_H).shape[-1]
    names = tuple(param_names(n))
    ps = PosteriorSamples(samples=np.asarray(nls.theta)[None], log_prob=np.full(1, np.nan),
                          scale=nls.scale, n=n, names=names, measured=measured_data(frf),
                          diagnostics={"fit_theta": np.asarray(nls.theta)})  # fmt: skip
    t0 = time.perf_counter()
    pd = plant_draws(ps, om, draws="loop_gp", max_samples=draws, seed=seed)
    t_pred = time.perf_counter() - t0
    nan = float("nan")
    return [{"device": name, "error model": "loop_gp", "quantity": q, "band": band, **c,
             "eval_ms": nan, "build_s": nan, "posterior_s": nan, "predict_s": t_pred,
             "n_held_out": k, "tau": nan, "steps_over_tau": nan}
            for q in quantities if q == "P"
            for band, c, k in split_figures(pd.P, tr[q], om / TWO_PI, split_hz)]  # fmt: skip


def fit(frf, weight: str = "relative"):
    """The NLS fit of the calibration (≤ 40 Hz, ``weight``), with more Levenberg–Marquardt
    steps when the default 500 do not converge (hexapod6 with a 2-sample delay)."""
    nls = fit_nls(frf, weight=weight, f_max_hz=40.0)
    if not nls.ok:
        nls = fit_nls(frf, weight=weight, f_max_hz=40.0, max_steps=5000)
    return nls.raise_if_failed()


def log_posterior(frf, nls, model_error):
    """The posterior of the calibration (≤ 40 Hz, the NLS fit as reference, parameters at a
    PD boundary held fixed) with ``model_error``."""
    fixed = boundary_fixed(nls) if nls.boundary else None
    return make_log_posterior(frf, nls.scale, f_max_hz=40.0, model_error=model_error,
                              reference=nls, fixed=fixed)  # fmt: skip


def calibrate(name: str, kinds=("white", "gp", "gp_corr"), method="laplace", draws=400, seed=0,
              quantities=("P", "Z_H", "Z_T"), split_hz=None, holdout=False,
              recalibrate=False, force_noise=None):  # fmt: skip
    dev = device(name)
    noise = 5e-3 if not isinstance(dev, SecondOrderDevice) else 2e-2
    noise = noise if force_noise is None else float(force_noise)
    pattern = "hadamard" if dev.n < 3 else "paper"  # the paper's pattern is singular for n = 2
    exact = name == "second_order_exact"
    if exact:  # the model class exactly right and the FRF's std the whole data error
        proto = Protocol(seed=seed, force_noise=noise, pattern=pattern, position_noise=2e-6,
                         encoder_resolution=0.0)  # fmt: skip
        run = periodic_run(dev, proto, hold="bandlimited")
    else:
        run = periodic_run(dev, Protocol(seed=seed, force_noise=noise, pattern=pattern))
    frf = estimate_frf(run)
    weight = "relative" if not isinstance(dev, SecondOrderDevice) else "noise"
    if weight == "noise" and np.any(np.asarray(frf.Z_T_std) <= 0):  # force noise only: Z_T exact
        weight = "relative"
    nls = fit(frf, weight)
    om = held_out_grid(np.asarray(frf.omega) / TWO_PI)
    tr = truth(dev, om, exact)
    rows = []
    for kind in kinds:
        if kind == "loop_gp":
            rows += _loop_gp_rows(name, frf, nls, om, tr, draws, seed, quantities, split_hz)
            continue
        base, _, mode = kind.partition("@")  # e.g. "gp_corr@map": the hyperparameters' fixing
        me = model_error_from("gp_corr" if base == "gp_corr_el" else base, gp_hyper=mode or None,
                              error_scale="element" if base == "gp_corr_el" else None)  # fmt: skip
        t0 = time.perf_counter()
        post = log_posterior(frf, nls, me)
        t_build = time.perf_counter() - t0
        ms = _eval_ms(post, initial_point(post, nls))
        t0 = time.perf_counter()
        if method == "laplace":
            ps = posterior_laplace_samples(post, draws, nls, key=seed)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ShortChainWarning)
                ps = sample_posterior(post, nls, moves="de", seed=seed)
        t_post = time.perf_counter() - t0
        t0 = time.perf_counter()
        pred = predictive_plants(ps, om, max_samples=draws, seed=seed)
        t_pred = time.perf_counter() - t0
        check = holdout_check(ps, max_samples=draws, seed=seed) if holdout or recalibrate else None
        if holdout:
            gaps = ", ".join(f"{a:g}–{b:g}" for a, b in check.not_established_hz) or "none"
            print(f"<!-- {name} seed {seed}: check {check.status}; not established (Hz): "
                  f"{gaps}; ratio min {check.ratio.min():.2f} -->", flush=True)  # fmt: skip
        # (label, quantity, draws, check for the est./flagged rows)
        series = [(kind, q, getattr(pred, q), check if holdout else None) for q in quantities]
        if recalibrate and "P" in quantities:  # hapid predict's default band
            recal = recalibration(check, om / TWO_PI).apply(pred.P, seed=seed)
            series.append((f"{kind} recal.", "P", recal, None))
        d = ps.diagnostics
        for label, q, X, chk in series:
            for band, c, k in split_figures(X, tr[q], om / TWO_PI, split_hz, chk):
                rows.append({"device": name, "error model": label, "quantity": q, "band": band,
                             **c, "eval_ms": ms, "build_s": t_build, "posterior_s": t_post,
                             "predict_s": t_pred, "n_held_out": k,
                             "tau": d.get("tau_max", np.nan),
                             "steps_over_tau": d.get("steps_over_tau", np.nan)})  # fmt: skip
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", choices=["laplace", "emcee"], default="laplace")
    ap.add_argument("--draws", type=int, default=400)
    ap.add_argument("--devices", default="cu5,tripod3_d2,second_order")
    ap.add_argument("--family", choices=sorted(FAMILIES),
                    help="the devices of a held-out family (module docstring) instead of --devices")  # fmt: skip
    ap.add_argument("--kinds", default="white,gp,gp_corr",
                    help="model errors to compare: white, gp, gp_corr, gp_corr_el (gp_corr "
                         "with scale='element'), loop_gp (loop draws conditioned on the "
                         "measured FRF); kind@mode sets how the hyperparameters are fixed "
                         "(e.g. gp@sample, gp_corr@map)")  # fmt: skip
    ap.add_argument(
        "--quantities", default="P,Z_H,Z_T", help="responses compared (loop_gp draws have P only)"
    )
    ap.add_argument("--seeds", default="0",
                    help="comma-separated seeds of the experiment's noise, the posterior and the "
                         "draws: one row per device, kind and seed (the spread of the figures "
                         "over noise realizations)")  # fmt: skip
    ap.add_argument("--split-hz", type=float, default=None,
                    help="also give each band's figures below and at or above this frequency "
                         "(Hz): where it is wide or short")  # fmt: skip
    ap.add_argument("--holdout", action="store_true",
                    help="also run hapid predict's leave-one-frequency-out check "
                         "(hapid.uncertainty.holdout_check) and give the band's figures where it "
                         "leaves the band established and where it flags it")  # fmt: skip
    ap.add_argument("--recalibrate", action="store_true",
                    help="also give the figures of the P band recalibrated on the check's "
                         "left-out errors (hapid.uncertainty.recalibration; hapid predict's "
                         "default): rows 'KIND recal.'")  # fmt: skip
    ap.add_argument("--force-noise", type=float, default=None,
                    help="the experiment's force-sensor noise std (N per sample; default 5e-3, "
                         "2e-2 on the second-order devices)")  # fmt: skip
    a = ap.parse_args(argv)
    print(f"posterior: {a.method}; 90 % predictive band; held-out frequencies in 1–40 Hz\n")
    print("| device | seed | model error | quantity | band | coverage | width / error | calibrated | "
          "element coverage | rel. error of median | rel. radius | eval ms | build s | "
          "posterior s | τ | steps/τ | predict s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    from calibrate_robust import split_specs

    seeds = [int(x) for x in a.seeds.split(",")]
    for name in FAMILIES[a.family] if a.family else split_specs(a.devices):
        for seed in seeds:
            for r in calibrate(name, kinds=a.kinds.split(","), method=a.method, draws=a.draws,
                               seed=seed, quantities=a.quantities.split(","),
                               split_hz=a.split_hz, holdout=a.holdout,
                               recalibrate=a.recalibrate, force_noise=a.force_noise):  # fmt: skip
                print(f"| {r['device']} | {seed} | {r['error model']} | {r['quantity']} | "
                  f"{r['band']} | {r['coverage']:.3f} | "
                  f"{r['width_ratio']:.2f} | {r['width_ratio_calibrated']:.2f} | "
                  f"{r['element_coverage']:.3f} | {r['rel_error_median']:.4f} | "
                  f"{r['rel_radius_median']:.4f} | {r['eval_ms']:.2f} | "
                  f"{r['build_s']:.1f} | {r['posterior_s']:.1f} | {r['tau']:.0f} | "
                  f"{r['steps_over_tau']:.1f} | {r['predict_s']:.1f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
