"""What binds the loop-GP robust design of g(s) (issue 14), and does more freedom in g help?

For a device (development devices only: cu5, tripod3, …) the paper's experiment is simulated
with the dense FRF (every 1 Hz to 60 Hz), the NLS model fitted, and g tuned by
``hapid.tune.robust_design(draw_family="loop_gp")`` — the route of
``paper_figures/robust_table.py --draws loop_gp --freqs dense`` — from a *template* g0 that fixes
the tuned structure (``hapid.tune.extend_structure``: the paper g with identity lag/lead pairs
or notches added, so every template starts from the paper g's response). Then, at the tuned
optimum:

1. **Diagnosis** (:func:`diagnose`): every constraint of the smooth problem evaluated exactly
   (no soft maximum) on the same scenarios the tuner used (rebuilt with the same seed,
   :func:`problem`) — the posterior (loop-GP) chance constraint with the frequencies of its
   K worst draws, the measured-FRF disc at each measured frequency, the small gain beyond the
   FRF, the |g(0)| floor, the box on g's frequencies — with the penalty's multiplier estimate
   ``λ_j = 2 μ max(0, c_j)`` (``∂ ln ω_b / ∂ relaxation of c_j`` in log units at the final
   μ). The true plant's own limit (where its loci come closest to −1, where σ̄(S) first
   crosses the iso-bandwidth threshold) is printed beside it.
2. **Relax one at a time** (:func:`relax`, ``--relax``): the tuner is restarted from the tuned
   g with one constraint removed or loosened, and the gain in claimed bandwidth and on the
   true plant (non-smooth analysis, :func:`hapid.tune.true_plant_loop`) measured.

    PYTHONPATH=. python benchmarks/binding_limit.py --device cu5 --structure paper \\
        [--relax frf small_gain dc posterior box] [--n-train 150 --n-holdout 150]
    PYTHONPATH=. python benchmarks/binding_limit.py --device cu5 --extra-lag 19 --extra-notch 45
    # a richer template continued from an earlier run's tuned g (warm start, same problem):
    PYTHONPATH=. python benchmarks/binding_limit.py --device tripod3 \
        --continue-from out/binding/tripod3-paper.json --extra-lag 19 --extra-notch 150
    # the template tuned on the true plant itself (alone / + small gain / + FRF disc):
    PYTHONPATH=. python benchmarks/binding_limit.py --device cu5 --oracle

The numbers and their commands: docs/robust-design.md, "What binds the loop-GP design".

Writes ``out/binding/<device>-<structure>.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "paper_figures"))


def problem(model, frf, dev, g0, *, n_train=150, n_freq=200, dense_factor=4, seed=0,
            quantile=0.975, kappa=None):  # fmt: skip
    """The families and requirements ``robust_design(draw_family="loop_gp", frf=frf,
    evidence_ts=dev.ts, keep_dc_gain=True)`` builds (same seed, same grids), for diagnosis and
    relaxation. Returns a dict ``families, requirements, f_max_hz, evidence``."""
    from hapid._constants import TWO_PI
    from hapid._grids import continuous_grid
    from hapid.tune import Family, Requirements, make_scenarios
    from hapid.tune._evidence import KAPPA, beyond_grid, evidence_from_frf, measured_plant
    from hapid.uncertainty._loopgp import fit_loop_gp, loop_gp_plants

    omc = continuous_grid(n_freq)
    lgp = fit_loop_gp(np.asarray(frf.omega), measured_plant(frf.Z_H, frf.Z_T), model)
    omc_d = continuous_grid(dense_factor * n_freq)
    P_all = loop_gp_plants(lgp, model, np.concatenate([omc, omc_d]), n_train, seed)
    dense = make_scenarios(P_all[:, omc.size :], model, omc_d)
    post = Family(make_scenarios(P_all[:, : omc.size], model, omc), quantile=quantile,
                  bandwidth=True, bw_quantile=0.5, name="posterior", dense=dense)  # fmt: skip
    ev = evidence_from_frf(frf, model, kappa=KAPPA if kappa is None else kappa, ts=dev.ts)
    fam_frf = Family(make_scenarios(ev.P, model, ev.omega, ts=ev.ts), quantile=1.0,
                     bandwidth=False, name="frf", contour=False)  # fmt: skip
    req = Requirements(min_dc_gain=float(np.abs(g0(np.array([0.0]))[0])),
                       sg_omega=tuple(beyond_grid(ev)), sg_g_max=ev.g_max, sg_ts=ev.ts)  # fmt: skip
    return {"families": [post, fam_frf], "requirements": req, "evidence": ev, "loop_gp": lgp,
            "f_max_hz": float(omc[-1]) / TWO_PI / 4.0, "seed": seed}  # fmt: skip


def recheck(g, model, prob, n_holdout: int, n_freq: int = 600) -> dict:
    """The re-check ``robust_design`` makes of a design: held-out loop-GP draws (seed + 1,
    ``n_freq`` points of the continuous grid, fraction meeting 6 dB / 30°, non-smooth) and the
    evidence certificate (measured-FRF return difference, loop gain beyond the FRF)."""
    from hapid._grids import continuous_grid
    from hapid.tune import validate
    from hapid.tune._check import FRF_FLOOR
    from hapid.tune._evidence import certificate
    from hapid.tune._validate import table_row
    from hapid.uncertainty._loopgp import loop_gp_plants

    om = continuous_grid(n_freq)
    hold = loop_gp_plants(prob["loop_gp"], model, om, n_holdout, prob["seed"] + 1)
    v = validate(g, model, samples=hold, omega_c=om, p_required=0.975)
    row = table_row(v) | certificate(prob["evidence"], model, g, floor=FRF_FLOOR).figures()
    keep = ("posterior_frac_meeting_margins", "certified", "frf_min_sigma_I_plus_L",
            "beyond_loop_gain")  # fmt: skip
    return {k: row.get(k) for k in keep}


def diagnose(g, prob, constraints: dict | None = None, mu: float = 1e4) -> dict:
    """:func:`hapid.tune.binding_constraints` on the rebuilt problem (exact values, where they
    act, multiplier estimates from the tuner's final smooth ``constraints`` at penalty ``mu``)."""
    from hapid.tune import binding_constraints

    b = binding_constraints(g, prob["families"], prob["requirements"],
                            f_max_hz=prob["f_max_hz"], constraints=constraints, mu=mu)  # fmt: skip
    return b.summary()["constraints"]


def true_limits(g, model, dev, n: int = 2000) -> dict:
    """On the device's true sampled plant: the iso-bandwidth frequency (first crossing of
    σ̄(S) over the threshold) and the frequency where the loci come closest to −1."""
    from hapid._constants import TWO_PI
    from hapid._grids import below_nyquist_grid
    from hapid.control import ISO_THRESHOLD
    from hapid.tune import make_scenarios
    from hapid.tune._response import g_response

    om = below_nyquist_grid(dev.fs_hz, n)
    sc = make_scenarios(np.asarray(dev.sampled_P(om)), model, om, ts=dev.ts)
    gam = np.asarray(g_response(g, sc.omega, sc.ts))
    lam = np.asarray(sc.lam)[0]
    d = 1.0 + gam[:, None] * lam
    S = (np.asarray(sc.V)[0] * (1.0 / d)[:, None, :]) @ np.asarray(sc.Vi)[0]
    s = np.linalg.svd(S, compute_uv=False)[:, 0]
    over = np.nonzero(s > ISO_THRESHOLD)[0]
    i = int(np.abs(d).min(axis=1).argmin())
    return {"sigma_S_crossing_hz": float(om[over[0]] / TWO_PI) if over.size else None,
            "closest_to_minus1_hz": float(om[i] / TWO_PI),
            "min_abs_1_plus_l": float(np.abs(d).min())}  # fmt: skip


RELAX = ("none", "frf", "small_gain", "dc", "posterior", "box")


def relax(which: str, g, prob, *, max_steps=150, mu_schedule=(1e3, 1e4)):
    """Restart the tuner from ``g`` with constraint ``which`` removed (``frf``: the measured
    FRF disc; ``small_gain``: the bound beyond the FRF; ``dc``: the |g(0)| floor;
    ``posterior``: the loop-GP draws' margins (they still claim the bandwidth); ``box``: g's
    frequencies up to 4× the box's top and notch damping ratios up to 8 instead of 2). Returns the :class:`TuneResult`."""
    from hapid.tune import tune

    fams, req = list(prob["families"]), prob["requirements"]
    f_max = prob["f_max_hz"]
    if which == "none":  # the same problem (a warm start / a richer template)
        pass
    elif which == "frf":
        fams = fams[:1]
    elif which == "small_gain":
        req = dataclasses.replace(req, sg_omega=None, sg_g_max=None)
    elif which == "dc":
        req = dataclasses.replace(req, min_dc_gain=None)
    elif which == "posterior":
        fams[0] = dataclasses.replace(fams[0], margins=False)
    elif which == "box":  # frequencies to 4× the top, notch damping ratios to 8 (default 2)
        from hapid.tune._objective import Box
        from hapid.tune._params import ParamMap

        pm = ParamMap.from_template(g)
        box = Box.default(pm, 4.0 * f_max)
        zeta = np.array([n.startswith("notch ζ") for n in pm.names])
        box = Box(box.lo, np.where(zeta, np.log(8.0), box.hi))
    else:
        raise ValueError(f"relax: one of {RELAX}, got {which!r}")
    return tune(fams, g, requirements=req, mu_schedule=mu_schedule, max_steps=max_steps,
                f_max_hz=f_max, box=box if which == "box" else None)  # fmt: skip


def oracle(g0, model, frf, dev, *, max_steps=300) -> dict:
    """What the template ``g0`` reaches when the plant is KNOWN: tuned on the device's true
    sampled plant itself (one scenario, 300 points, |g(0)| ≥ the paper g's), alone, with the
    small-gain bound beyond the FRF, and with that bound and the measured-FRF disc. Not a
    design method: the measurement of which limit binds when the draws are taken out."""
    from hapid._grids import below_nyquist_grid
    from hapid.control import Compensator
    from hapid.tune import Family, binding_constraints, make_scenarios, tune

    prob = problem(model, frf, dev, Compensator.paper(), n_train=2)
    om = below_nyquist_grid(dev.fs_hz, 300)
    fam = Family(make_scenarios(np.asarray(dev.sampled_P(om)), model, om, ts=dev.ts),
                 quantile=1.0, name="true")  # fmt: skip
    req, fam_frf = prob["requirements"], prob["families"][1]
    f_max = 0.45 * dev.fs_hz
    out = {}
    for lab, fams, rq in (
        ("true plant", [fam], dataclasses.replace(req, sg_omega=None, sg_g_max=None)),
        ("true plant + small gain", [fam], req),
        ("true plant + small gain + FRF disc", [fam, fam_frf], req),
    ):
        t0 = time.perf_counter()
        r = tune(fams, g0, requirements=rq, max_steps=max_steps, f_max_hz=f_max)
        b = binding_constraints(r.g, [fam, fam_frf], req, f_max_hz=f_max)
        out[lab] = {"claimed_hz": r.bandwidth_hz, "feasible": r.feasible,
                    "true": _true(r.g, model, dev),
                    "beyond_loop_gain": float(req.sg_g_max * np.exp(b["evidence/small_gain"].value)
                                              * prob["evidence"].mismatch),
                    "frf_disc": b["frf/ms"].value, "true_limits": true_limits(r.g, model, dev),
                    "wall_s": time.perf_counter() - t0}  # fmt: skip
        print(lab, json.dumps(out[lab], default=float), flush=True)
    return out


def _true(g, model, dev):
    from hapid.tune import true_plant_loop

    t = true_plant_loop(g, model, dev).numbers()
    return {k: t[k] for k in ("stable", "iso_bandwidth_hz", "gm_db", "pm_deg")}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cu5")
    ap.add_argument("--extra-lag", type=float, nargs="*", default=[],
                    help="add a lag/lead pair (identity at the start) at these frequencies (Hz)")  # fmt: skip
    ap.add_argument("--extra-notch", type=float, nargs="*", default=[],
                    help="add a notch (identity at the start) at these frequencies (Hz)")  # fmt: skip
    ap.add_argument("--relax", nargs="*", default=[], choices=RELAX)
    ap.add_argument("--n-train", type=int, default=150)
    ap.add_argument("--n-holdout", type=int, default=150)
    ap.add_argument("--max-steps", type=int, default=150)
    ap.add_argument("--design", help="reuse the tuned g of an earlier run's JSON (skip tuning)")
    ap.add_argument("--continue-from", help="an earlier run's JSON: add --extra-lag/--extra-notch to "
                    "ITS tuned g and continue tuning on the same problem (warm start)")  # fmt: skip
    ap.add_argument("--out", default=str(ROOT / "out" / "binding"))
    ap.add_argument("--oracle", action="store_true",
                    help="instead: tune the template on the true plant (alone / + small gain / + FRF disc)")  # fmt: skip
    a = ap.parse_args(argv)
    from robust_table import DENSE_FREQS, design

    import hapid  # noqa: F401
    from hapid import scene
    from hapid.control import Compensator
    from hapid.tune import extend_structure

    g0 = extend_structure(Compensator.paper(), lag_hz=a.extra_lag, notch_hz=a.extra_notch)
    tag = (
        "paper"
        + "".join(f"+lag{f:g}" for f in a.extra_lag)
        + "".join(f"+notch{f:g}" for f in a.extra_notch)
    )
    cfg = {"device": {"preset": a.device}, "protocol": {"freqs": DENSE_FREQS}}
    res = scene.run_scene(scene.merge(cfg), ["device", "frf", "nls"],
                             cache_dir=str(ROOT / ".hapid_cache" / "stages"),
                             out_dir=str(ROOT / "out" / "robust")).results  # fmt: skip
    dev, frf, model = res["device"], res["frf"], res["nls"]["model"]
    rec = {"device": a.device, "structure": tag, "n_train": a.n_train, "n_holdout": a.n_holdout}
    if a.oracle:
        rec["oracle"] = oracle(g0, model, frf, dev)
        Path(a.out).mkdir(parents=True, exist_ok=True)
        path = Path(a.out) / f"{a.device}-{tag}-oracle.json"
        path.write_text(json.dumps(rec, indent=1, default=float))
        print(f"→ {path}")
        return 0
    if a.continue_from:
        old = json.loads(Path(a.continue_from).read_text())
        g1 = Compensator(**{k: np.asarray(v) for k, v in old["g"].items()})
        tpl = extend_structure(g1, lag_hz=a.extra_lag, notch_hz=a.extra_notch)
        tag = f"{old['structure']}-then-{tag}"
        rec["structure"] = tag
        prob = problem(model, frf, dev, Compensator.paper(), n_train=a.n_train)
        t0 = time.perf_counter()
        r = relax("none", tpl, prob, max_steps=a.max_steps)
        g, constraints, mu = r.g, r.constraints, r.history[-1]["mu"]
        rec |= {"claimed_bandwidth_hz": [r.bandwidth0_hz, r.bandwidth_hz], "constraints": constraints,
                "parameters": r.parameters(), "feasible": r.feasible,
                "wall_s": time.perf_counter() - t0,
                "rows": {"start": _true(g1, model, dev) | recheck(g1, model, prob, a.n_holdout),
                         "tuned g": _true(g, model, dev) | recheck(g, model, prob, a.n_holdout)}}  # fmt: skip
        print(json.dumps(rec["rows"], indent=1, default=float))
    elif a.design:
        old = json.loads(Path(a.design).read_text())
        g = Compensator(**{k: np.asarray(v) for k, v in old["g"].items()})
        constraints, mu = old.get("constraints"), 1e4
        rec |= {k: old[k] for k in old if k not in ("diagnosis", "true_limits")}
    else:
        t0 = time.perf_counter()
        row, out = design(a.device, quick=True, draws="loop_gp", g0=g0,
                          protocol={"freqs": DENSE_FREQS}, n_train=a.n_train,
                          n_holdout=a.n_holdout, keep_dc_gain=True)  # fmt: skip
        cand = out["candidate"]
        g, constraints, mu = cand.g, cand.constraints, cand.history[-1]["mu"]
        rec |= {"rows": row["rows"], "claimed_bandwidth_hz": row["claimed_bandwidth_hz"],
                "decision": row["decision"], "kept_start": row["kept_start"],
                "constraints": constraints, "parameters": row["parameters"],
                "history": row["history"],
                "wall_s": time.perf_counter() - t0}  # fmt: skip
        print(json.dumps(row["rows"], indent=1, default=float))
    rec["g"] = {f: np.asarray(getattr(g, f)).tolist() for f in
                ("k", "lag_zeros", "lag_poles", "notch_omega", "notch_zeta_num", "notch_zeta_den", "lowpass")}  # fmt: skip
    if not a.continue_from:
        prob = problem(model, frf, dev, g0, n_train=a.n_train)
    rec["diagnosis"] = diagnose(g, prob, constraints, mu)
    rec["true_limits"] = true_limits(g, model, dev)
    for name, e in rec["diagnosis"].items():
        print(
            f"{name:22s} {'ACTIVE' if e['active'] else 'slack '} "
            + json.dumps({k: v for k, v in e.items() if k != "active"}, default=float)
        )
    print("true plant:", rec["true_limits"], _true(g, model, dev))
    Path(a.out).mkdir(parents=True, exist_ok=True)
    path = Path(a.out) / f"{a.device}-{tag}.json"
    path.write_text(json.dumps(rec, indent=1, default=float))
    rec["relax"] = rec.get("relax", {})
    for which in a.relax:
        t0 = time.perf_counter()
        r = relax(which, g, prob, max_steps=a.max_steps)
        rec["relax"][which] = {"claimed_hz": [r.bandwidth0_hz, r.bandwidth_hz],
                               "true": _true(r.g, model, dev),
                               "constraints": r.constraints, "wall_s": time.perf_counter() - t0}  # fmt: skip
        print(f"relax {which}: claimed {r.bandwidth0_hz:.2f} → {r.bandwidth_hz:.2f} Hz; true plant "
              f"{rec['relax'][which]['true']} ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
        path.write_text(json.dumps(rec, indent=1, default=float))
    print(f"→ {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
