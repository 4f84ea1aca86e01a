"""Benchmark: gradient tuning of g(s) (hapid.tune) on cu5 with the paper protocol.

Run: ``.venv/bin/python benchmarks/bench_tune.py [--quick] [--out out/bench]``.
Prints machine and versions, the cost of one objective + gradient evaluation, the tuning
wall time, and paper g vs tuned g re-checked with the non-smooth analysis on held-out
Laplace samples, held-out device variants, the true plant and in the time domain.
``--quick``: 10 training / 20 held-out samples, 150-point grid, two penalty stages.

Recorded (x86_64, 2 cores shared with 3 other JAX jobs, load ≈ 10, python 3.11, jax 0.10.2):
``--quick``: 62 s in all; paper g → tuned g on the true cu5 plant 5.95 → 6.33 Hz iso
bandwidth, GM 3.9 → 6.8 dB, PM 28.7° → 32.9°. Full settings (``hapid tune --model nls.npz
--samples samples.npz --device cu5``: 80 training / 200 held-out Laplace samples, 6 poses +
16 subjects, 300 frequencies, 3 stages × ≤ 300 BFGS steps): tuning 76 s, with re-check
140 s; true plant 5.95 → 5.48 Hz, GM 3.9 → 6.8 dB, PM 28.7° → 54.1°, disk margin 0.40 → 0.72;
held-out variants P(stable) 1.0 → 1.0, meeting both margins 0/8 → 6/8; held-out posterior
P(stable) 0.99 → 0.99, meeting both margins 73.5 % → 72.5 %; step overshoot 20 % → 3.5 %.

``--devices SPEC [SPEC …]`` (``preset[:delay=S][:compliance=F]``, development devices only):
instead, ``hapid tune``'s default route on each device — paper protocol, NLS fit
(``control_fit``), loop draws conditioned on the measured FRF, evidence 1–100 Hz with
the 1 kHz controller, certificate and fallback (60 training / 100 held-out draws, 200-point
grid, 150 BFGS steps per stage) — and the paper g and the returned g on the device's true
sampled plant: the collapse check of docs/robust-design.md ("The collapse").
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Section, fs, measure, standalone, table  # noqa: E402

import hapid  # noqa: E402,F401
from hapid._constants import TWO_PI
from hapid.control import Compensator  # noqa: E402
from hapid.scene import merge, run_scene  # noqa: E402
from hapid.tune import (  # noqa: E402
    Box,
    Family,
    ParamMap,
    Recipe,
    Requirements,
    make_scenarios,
    penalized,
    robust_design,
)
from hapid.uncertainty import (  # noqa: E402
    LoopDraws,
    ParamDraws,
    laplace_samples,  # noqa: E402
)


def _fmt(v):
    if isinstance(v, bool) or v is None:
        return str(v)
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def run(quick: bool = False, out: str = "out/bench") -> Section:
    sec = Section("Gradient tuning of g(s), robust over posterior samples and device variants")
    res = run_scene(
        merge({}), ["device", "nls"], cache_dir=".hapid_cache/stages", out_dir=out
    ).results
    dev, nls = res["device"], res["nls"]
    model = nls["model"]
    g0 = Compensator.paper()
    ps = laplace_samples(nls["result"], 400 if quick else 1000, key=0)
    N = 150 if quick else 300
    # one objective + gradient evaluation on the device variants' scenario batch
    om = TWO_PI * np.geomspace(0.1, 0.499 * dev.fs_hz, N)
    from hapid.uncertainty import device_plants

    _, P = device_plants(dev, om, n_subjects=8, key=1, include_nominal=True)
    sc = make_scenarios(P, model, om, ts=dev.ts)
    pm = ParamMap.from_template(g0)
    x0 = pm.vector(g0)
    z = jnp.concatenate([x0, jnp.array([np.log(TWO_PI * 5.0)])])
    fams = [Family(sc, quantile=1.0)]
    box = Box.default(pm, 450.0)
    vg = jax.jit(
        jax.value_and_grad(lambda z: penalized(z, 100.0, pm, fams, Requirements(), box, x0, 1e-4))
    )
    _, first, med = measure(lambda: vg(z))
    sec.add(table([{"case": f"objective + gradient, {sc.n_scenarios} plants × {N} freqs × n = {dev.n}",
                    "compile+first": fs(first), "per call": fs(med)}]))  # fmt: skip
    recipe = Recipe(n_train=10 if quick else 40, n_holdout=20 if quick else 200,
                    n_subjects=2 if quick else 4, n_holdout_subjects=2 if quick else 4, n_freq=N,
                    mu_schedule=(1e2, 1e4) if quick else (1e2, 1e3, 1e4), max_steps=150 if quick else 300)  # fmt: skip
    d = robust_design(model, ParamDraws(ps), evidence=ps.predictive, device=dev, recipe=recipe)
    r = d.result
    sec.add(
        f"tuning: {r.wall_s:.1f} s, {sum(h['steps'] for h in r.history)} BFGS steps, claimed robust "
        f"bandwidth {r.bandwidth0_hz:.2f} → {r.bandwidth_hz:.2f} Hz, smooth constraints met: {r.feasible}"
    )
    sec.add(
        table(
            [
                {"parameter": p["name"], "paper": f"{p['start']:.4g}", "tuned": f"{p['tuned']:.4g}"}
                for p in r.parameters()
            ]
        )
    )
    t = d.table
    rows = [
        {"quantity": k, "paper g": _fmt(t["start"][k]), "tuned g": _fmt(t["tuned"][k])}
        for k in t["tuned"]
    ]
    sec.add(table(rows))
    sec.rows = {"table": t, "families": d.families}
    tp, tt = t["start"], t["tuned"]
    bw_ok = (tt.get("true_iso_bandwidth_hz") or 0) >= 2 * (
        tp.get("true_iso_bandwidth_hz") or np.inf
    )
    sec.goal(
        "true plant: ≥ 2× paper-g iso bandwidth",
        f"{tp['true_iso_bandwidth_hz']:.2f} → {tt['true_iso_bandwidth_hz']:.2f} Hz",
        bw_ok,
    )
    sec.goal("true plant: GM ≥ 6 dB, PM ≥ 30°", f"{tt['true_gm_db']:.1f} dB, {tt['true_pm_deg']:.1f}°",
             tt["true_gm_db"] >= 6 and tt["true_pm_deg"] >= 30)  # fmt: skip
    if "posterior_frac_meeting_margins" in tt:
        sec.goal("held-out posterior: GM ≥ 6 dB and PM ≥ 30° on ≥ 95 %",
                 f"{tp['posterior_frac_meeting_margins']:.0%} → {tt['posterior_frac_meeting_margins']:.0%}",
                 tt["posterior_frac_meeting_margins"] >= 0.95)  # fmt: skip
    return sec


def devices_table(specs, n_train: int = 60, n_holdout: int = 100, seed: int = 0) -> str:
    """The collapse check (module docstring, ``--devices``): one markdown row per device and
    design (paper g, returned g), on the true sampled plant, with the held-out loop draws'
    fraction meeting 6 dB / 30°, the evidence certificate and the tuning wall time."""
    import time

    from calibrate_robust import parse_device, setup

    from hapid.tune import true_plant_loop

    lines = ["| device | g | true iso-bw (Hz) | GM (dB) | PM (°) | held-out draws meeting 6 dB / 30° "
             "| certified | stable on the true plant | tune + re-check (s) |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    notes = []
    for spec in specs:
        dev = parse_device(spec)
        frf, fit = setup(dev, seed)
        t0 = time.perf_counter()
        out = robust_design(fit.model, LoopDraws(frf), ts=dev.ts,
                            recipe=Recipe(n_train=n_train, n_holdout=n_holdout, n_freq=200,
                                          max_steps=150, seed=seed))  # fmt: skip
        wall = time.perf_counter() - t0
        tab = out.table
        ret = "returned" if "returned" in tab else "start" if out.kept_start else "tuned"
        for name, g, row in (("paper", Compensator.paper(), tab["start"]),
                             (f"returned ({ret})", out.g, tab[ret])):  # fmt: skip
            t = true_plant_loop(g, fit.model, dev).numbers()
            bw = t.get("iso_bandwidth_hz")
            lines.append(
                f"| {spec} | {name} | {_fmt(bw) if t['stable'] else '—'} | {_fmt(t.get('gm_db'))} | "
                f"{_fmt(t.get('pm_deg'))} | {100 * row.get('posterior_frac_meeting_margins', np.nan):.0f} % | "
                f"{row.get('certified')} | {t['stable']} | {'' if name == 'paper' else f'{wall:.0f}'} |"
            )
        c = out.candidate
        notes.append(f"{spec}: gain back-off {c.gain_backoff:.3g}, claimed {c.bandwidth0_hz:.3g} → "
                     f"{c.bandwidth_hz:.3g} Hz; {out.decision.reason}")  # fmt: skip
    return "\n".join(lines + [""] + notes)


def objective_forms(S: int = 150, N: int = 300, n: int = 5, repeat: int = 7) -> str:
    """The design objective's σ̄(S) bound and its gradient, two layouts side by side: a batched
    ``matmul`` of ``(S, N, n, n)`` complex matrices (before) and the entry-major broadcast
    sums of :func:`hapid.tune.scenario_constraints` (now), on random diagonalized loops; the
    median of ``repeat`` interleaved calls after a warm-up, and the largest relative gradient
    difference. ``python benchmarks/bench_tune.py --objective``."""
    import time

    from hapid.control._kernels import to_entries
    from hapid.tune._response import smooth_sigma_max_entries
    from hapid.tune._scenarios import Scenarios

    rng = np.random.default_rng(0)
    cplx = lambda *sh: rng.normal(size=sh) + 1j * rng.normal(size=sh)  # noqa: E731
    om = TWO_PI * np.geomspace(0.01, 500.0, N)
    sc = Scenarios(jnp.asarray(om), jnp.asarray(cplx(S, N, n)), jnp.asarray(cplx(S, N, n, n)),
                   jnp.asarray(cplx(S, N, n, n)), jnp.zeros(S), 0.0)  # fmt: skip
    req = Requirements()

    def before(g, u):  # the batched-matmul form
        d = 1.0 + g[None, :, None] * sc.lam
        X = (sc.V * (1.0 / d)[..., None, :]) @ sc.Vi
        A = jnp.swapaxes(jnp.conj(X), -1, -2) @ X  # the products as batched matmuls
        t0 = jnp.real(jnp.trace(A, axis1=-2, axis2=-1))
        B, acc = A / t0[..., None, None], jnp.log(t0)
        for i in range(1, 7):
            B = B @ B
            c = jnp.real(jnp.trace(B, axis1=-2, axis2=-1))
            B, acc = B / c[..., None, None], acc + jnp.log(c) / 2.0**i
        hS = 0.5 * acc
        lw = jnp.log(sc.omega)
        log_w = jax.nn.log_sigmoid((u - lw) / req.tau + 5.0)
        return jnp.sum(jax.nn.logsumexp(req.beta * (hS + log_w), axis=-1))

    g = Compensator.paper()
    gam = jnp.asarray(g.at_omega(jnp.asarray(om)))
    u = jnp.log(TWO_PI * 5.0)
    f_before = jax.jit(jax.grad(lambda gr, gi: before(gr + 1j * gi, u), argnums=(0, 1)))

    # both differentiated in g(jω) (g enters the objective only through it)
    def now_g(gr, gi):
        gg = gr + 1j * gi
        d = 1.0 + gg[None, :, None] * sc.lam
        r = jnp.moveaxis(1.0 / d, -1, 0)
        Ve, Vie = to_entries(sc.V), to_entries(sc.Vi)
        hS = smooth_sigma_max_entries(
            jnp.sum(Ve[:, :, None] * r[None, :, None] * Vie[None], axis=1)
        )
        lw = jnp.log(sc.omega)
        log_w = jax.nn.log_sigmoid((u - lw) / req.tau + 5.0)
        return jnp.sum(jax.nn.logsumexp(req.beta * (hS + log_w), axis=-1))

    f_now = jax.jit(jax.grad(now_g, argnums=(0, 1)))
    args = (jnp.real(gam), jnp.imag(gam))
    a, b = jax.block_until_ready(f_before(*args)), jax.block_until_ready(f_now(*args))
    diff = max(
        float(jnp.max(jnp.abs(x - y)) / jnp.max(jnp.abs(x))) for x, y in zip(a, b, strict=True)
    )
    tb, tn = [], []
    for _ in range(repeat):
        for f, acc in ((f_before, tb), (f_now, tn)):
            t = time.perf_counter()
            jax.block_until_ready(f(*args))
            acc.append(time.perf_counter() - t)
    mb, mn = float(np.median(tb)), float(np.median(tn))
    return table([{"σ̄(S) bound + gradient": f"{S} plants × {N} freqs × n = {n}",
                   "batched matmul (before)": fs(mb), "entry-major (now)": fs(mn),
                   "ratio": f"{mb / mn:.2f}×", "gradient rel. diff": f"{diff:.1e}"}])  # fmt: skip


def main(argv=None) -> Section | str:
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--objective" in argv:
        txt = objective_forms()
        print(txt)
        return txt
    if "--devices" in argv:
        i = argv.index("--devices")
        specs = [a for a in argv[i + 1 :] if not a.startswith("--")]
        txt = devices_table(specs)
        print(txt)
        return txt
    return standalone(run, __doc__, argv)


if __name__ == "__main__":
    main()
