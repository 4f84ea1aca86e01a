"""Gradient tuning of g(s): continuation on a quadratic penalty, BFGS (optimistix) per stage.

See :mod:`._objective` for the problem. Each stage minimizes the penalized objective for one
penalty weight μ (default 10² → 10⁴), warm-started from the previous stage; the claimed
bandwidth ``u = log ω_b`` starts at the smooth robust bandwidth of the initial g. Gradients
come from JAX through g's response and the diagonalized loops (no LAPACK in the gradient).
After each stage a non-smooth guard (:func:`phase_counts`) checks that no training
scenario's Nyquist count changed — the smooth margin constraints keep loci away from −1 at
the grid points, but a long BFGS step can jump a locus across it; the step is then halved
back towards the previous stage's point (``step_fraction`` in the history). The smooth
result is still *not* the verdict: re-check it with :func:`.validate`.
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from ..control import Compensator
from ._exchange import exchange
from ._objective import Box, Requirements, aggregate, penalized
from ._params import ParamMap
from ._response import g_response


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """Outcome of :func:`tune`.

    ``g`` tuned compensator, ``g0`` the start; ``x``, ``x0`` their log-parameters;
    ``bandwidth_hz`` the claimed smooth robust bandwidth ω_b/2π at the end (``bandwidth0_hz``
    at the start); ``constraints`` the final CVaR constraint values (≤ 0 met, in log
    units); ``gain_backoff`` the factor on ``k`` the tuner started from (< 1 when ``g0``
    left training scenarios unstable, :func:`gain_backoff`); ``history`` one dict per μ stage (μ, steps, result, claimed bandwidth,
    constraints, wall time); ``names`` parameter names; ``requirements``.
    """

    g: Compensator
    g0: Compensator
    x: np.ndarray
    x0: np.ndarray
    bandwidth_hz: float
    bandwidth0_hz: float
    constraints: dict
    history: list
    names: list
    requirements: Requirements
    wall_s: float
    gain_backoff: float = 1.0

    @property
    def feasible(self) -> bool:
        """Every smooth constraint met (to 1e-3 in log units) on the training scenarios."""
        return all(v <= 1e-3 for v in self.constraints.values())

    ok = property(
        lambda self: self.feasible, doc="The smooth constraints are met (:attr:`feasible`)."
    )
    status = property(
        lambda self: "feasible" if self.feasible else "infeasible",
        doc="``feasible``/``infeasible``.",
    )

    def summary(self) -> dict:
        """Plain-python summary: verdict, claimed bandwidths (Hz), constraints, parameters."""
        return {"ok": self.ok, "status": self.status, "bandwidth_hz": float(self.bandwidth_hz),
                "bandwidth0_hz": float(self.bandwidth0_hz), "gain_backoff": float(self.gain_backoff),
                "constraints": {k: float(v) for k, v in self.constraints.items()},
                "parameters": self.parameters(), "wall_s": float(self.wall_s)}  # fmt: skip

    def parameters(self) -> list[dict]:
        """Rows ``{name, start, tuned}`` (frequencies in Hz)."""
        pm = ParamMap.from_template(self.g0)
        a, b = pm.describe(self.x0), pm.describe(self.x)
        return [{"name": n, "start": a[n], "tuned": b[n]} for n in pm.names]


def phase_counts(g: Compensator, families) -> tuple[np.ndarray, np.ndarray]:
    """Net phase of ``det(I + g Q) = Π_i (1 + g λ_i)`` from DC to the top of each scenario's
    grid, in units of π (an even integer), and whether the grid resolved it (every step
    < π/2).

    The grid starts at a finite frequency where ``det(I + L)`` need not be near the real
    axis (measured on cu5 with 3 samples of delay: −89.9° at 0.1 Hz), so the net phase
    *along the grid* rounded to a multiple of π flips with any small step. Instead the phase
    is taken from DC (``det`` real and positive there) to the first point as that point's
    principal angle, and from the last point back to the real axis likewise: the count is
    ``2 · round((φ_unwrapped(ω_e) − arg det(ω_e)) / 2π)`` (:func:`_turns`), which changes
    only when a locus crosses −1 or an end point crosses the negative real axis.

    The closed-loop RHP-pole count of a scenario can only change when this count does (same
    open-loop poles, same grid): :func:`tune` uses it as the non-smooth guard that the smooth
    margin constraints cannot give — a BFGS step may jump a locus across −1 between iterates.
    Counted on the family's dense grid when it has one (:attr:`.Family.dense`).
    """
    per = [_family_counts(g, f) for f in families]
    return np.concatenate([p[2] for p in per]), np.concatenate([p[3] for p in per])


def _family_counts(g: Compensator, f):
    """One family's Nyquist counts on the grid :func:`phase_counts` uses (the dense one when
    there is one): ``(scenarios, g(jω) (N,), counts (S,), resolved (S,), nominal (S,))`` with
    ``nominal`` true where the count equals the nominal loop's ``(1 + g)^n``."""
    sc = f.scenarios if f.dense is None else f.dense
    gam = np.asarray(g_response(g, sc.omega, sc.ts))
    d = np.prod(1.0 + gam[None, :, None] * np.asarray(sc.lam), axis=-1)
    ang = np.unwrap(np.angle(d), axis=1)
    cnt = _turns(ang[:, -1], np.angle(d[:, -1]))
    res = np.all(np.abs(np.diff(ang, axis=1)) < np.pi / 2, axis=1)
    n = sc.lam.shape[-1]
    ang1 = np.unwrap(np.angle(1.0 + gam))
    ref = _turns(n * ang1[-1], np.angle((1.0 + gam[-1]) ** n))
    return sc, gam, cnt, res, same_count(cnt, ref)


def _turns(phi_end, arg_end):
    """``2 · round((φ_end − arg_end) / 2π)``: the phase (units of π) accumulated from DC along
    an unwrapped phase that starts at its principal value (``np.unwrap``), closed back to the
    real axis at the end."""
    return 2.0 * np.round((np.asarray(phi_end) - np.asarray(arg_end)) / (2.0 * np.pi))


def same_count(a, b):
    """Equal closed-loop counts from two :func:`phase_counts` results (even integers, units
    of π)."""
    return np.abs(np.asarray(a) - np.asarray(b)) < 1.0


def stable_scenarios(g: Compensator, families) -> list:
    """Per family, ``(S,)`` bool: is the closed loop of each scenario stable under ``g``
    (Nyquist count of :func:`phase_counts` equal to the nominal loop's ``(1 + g)^n``, grid
    resolved)? Only for families with ``quantile < 1`` (chance constraints) and scenarios with
    no open-loop RHP poles; else ``None`` / True (all scenarios counted, as the strict guard
    assumes)."""
    out = []
    for f in families:
        if f.quantile >= 1.0:
            out.append(None)
            continue
        sc, _, _, res, nominal = _family_counts(g, f)
        out.append(np.where(np.asarray(sc.p_ol) > 0, True, res & nominal))
    return out


def _start_ok(g: Compensator, families, ms: float | None = None) -> bool:
    """Does ``g`` leave no scenario of a strict family (``quantile`` 1) and at most ``K − 1``
    of a chance-constrained one with an unstable closed loop (the Nyquist count of
    :func:`phase_counts` against the nominal loop's ``(1 + g)^n``; scenarios with open-loop
    RHP poles or a grid that does not resolve the count are not judged)? With ``ms``: and
    with every counted locus outside the disc of radius ``1/ms`` around −1 (margins). On the
    family's dense grid when it has one (:attr:`.Family.dense`)."""
    for f in families:
        sc, gam, _, res, nominal = _family_counts(g, f)
        # unresolved grids are not judged (as in the guard); RHP open-loop poles neither
        bad = (np.asarray(sc.p_ol) == 0) & res & ~nominal
        if ms is not None and f.margins:
            d = np.abs(1.0 + gam[None, :, None] * np.asarray(sc.lam)).min(axis=(1, 2))
            bad |= d < 1.0 / ms
        if np.sum(bad) > (0 if f.quantile >= 1.0 else f.k_worst() - 1):
            return False
    return True


def gain_backoff(g: Compensator, families, ms: float = 1.0, alpha_min: float = 1e-3,
                 iters: int = 12):  # fmt: skip
    """``(g', α)``: the tuner's start when ``g`` leaves training scenarios unstable — ``g``
    with its gain ``k`` scaled by ``α < 1`` — else ``(g, 1.0)``.

    The tuner's topology guard keeps every stable scenario stable, and its smooth margin
    constraints cannot carry a locus across −1; from a start that is unstable on a scenario
    of a strict family (the paper g on cu5 with 3 samples of delay and compliant rods,
    measured) no stage can move. A lower gain everywhere stabilizes loops whose loci
    encircle −1 at high gain. ``α`` is the largest found (bisection in log α) at which the
    scenarios are stable as their families require *and* their loci stay outside the
    ``1/ms`` disc (:func:`_start_ok`); if no gain down to ``alpha_min`` meets the disc, half
    the largest stable gain (6 dB below the stability boundary); if none is stable, ``g``
    unchanged. The tuner then restores bandwidth and static gain (``min_dc_gain``)."""
    scaled = lambda a: eqx.tree_at(lambda c: c.k, g, g.k * a)  # noqa: E731

    def largest(pred):
        lo, hi = np.log(alpha_min), 0.0
        if not pred(scaled(alpha_min)):
            return None
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if pred(scaled(np.exp(mid))) else (lo, mid)
        return float(np.exp(lo))

    if _start_ok(g, families):
        return g, 1.0
    alpha = largest(lambda gg: _start_ok(gg, families, ms))
    if alpha is None:
        a_stable = largest(lambda gg: _start_ok(gg, families))
        if a_stable is None:
            return g, 1.0
        alpha = 0.5 * a_stable
    return scaled(alpha), alpha


def smooth_bandwidth(g: Compensator, families, req: Requirements, n_grid: int = 200) -> float:
    """Largest ω_b (rad/s) on a log grid whose aggregated bandwidth constraints are all ≤ 0
    (the smooth robust bandwidth of ``g``); the grid's lowest point if none."""
    om = np.asarray(families[0].scenarios.omega)
    us = np.linspace(np.log(om[0]), np.log(om[-1]), n_grid)
    fams = [f for f in families if f.bandwidth]
    if not fams:
        raise ValueError("no family constrains the bandwidth")

    @jax.jit
    def worst(u):
        c = aggregate(g, fams, u, req)
        return jnp.max(jnp.stack([v for k, v in c.items() if k.endswith("/bw")]))

    vals = np.array([float(worst(u)) for u in us])
    ok = np.nonzero(vals <= 0.0)[0]
    if ok.size == 0:
        return float(np.exp(us[0]))
    # the first violation ends the feasible stretch (c_bw grows with u)
    bad = np.nonzero(vals > 0.0)[0]
    k = (bad[0] - 1) if bad.size and bad[0] > 0 else ok[-1]
    return float(np.exp(us[max(k, 0)]))


def tune(
    families,
    g0: Compensator | None = None,
    *,
    requirements: Requirements | None = None,
    box: Box | None = None,
    mu_schedule=(100.0, 1e3, 1e4),
    max_steps: int = 300,
    rho: float = 1e-4,
    f_max_hz: float | None = None,
    progress=None,
    max_exchanges: int = 4,
) -> TuneResult:
    """Tune g's parameters (log coordinates) for the largest robust isotropic bandwidth.

    - ``families``: list of :class:`.Family` (scenario plants with a required quantile).
    - ``g0``: starting compensator, also fixing the structure (default the paper's g).
    - ``requirements``: :class:`.Requirements` (6 dB, 30°, threshold 0.293).
    - ``box``: soft box on the log-parameters (default :meth:`.Box.default` with frequencies
      up to ``f_max_hz``: 0.45·f_s for a sampled design, else a quarter of the grid's top).
    - ``mu_schedule``, ``max_steps``: continuation stages and BFGS steps per stage.
    - ``rho``: weight of ``‖x − x₀‖²`` (keeps flat directions near the start).
    - ``max_exchanges``: how many times, in all, a stage may be repeated after families with a
      dense grid (:attr:`.Family.dense`) had violated frequencies added to their training
      grid (:mod:`._exchange`; ``history[i]["grid_added"]`` counts them per family).
    """
    t0 = time.perf_counter()
    families = list(families)
    if not families:
        raise ValueError("tune: no scenario families")
    req = Requirements() if requirements is None else requirements
    g0 = Compensator.paper() if g0 is None else g0
    pm = ParamMap.from_template(g0)
    x_given = pm.vector(g0)
    g_start, alpha = gain_backoff(g0, families, req.ms)
    x0 = pm.vector(g_start)
    if f_max_hz is None:
        ts = next((f.scenarios.ts for f in families if f.scenarios.ts), None)
        top = min(float(f.scenarios.omega[-1]) for f in families) / TWO_PI
        # a sampled g lives below Nyquist; a continuous one must roll off inside the grid
        f_max_hz = 0.45 / ts if ts else top / 4.0
    box = Box.default(pm, f_max_hz) if box is None else box
    wb0 = smooth_bandwidth(g_start, families, req)
    z = jnp.concatenate([x0, jnp.array([np.log(wb0)])])
    scens = [f.scenarios for f in families]

    def rebuild(sc):
        return [dataclasses.replace(f, scenarios=s) for f, s in zip(families, sc, strict=True)]

    def fn(z, args):
        mu, sc, counted = args
        return penalized(z, mu, pm, rebuild(sc), req, box, x0, rho, counted)

    @eqx.filter_jit
    def cons(z, sc, counted):
        return aggregate(pm.compensator(z[:-1]), rebuild(sc), z[-1], req, counted)

    def counted_at(zc):
        st = stable_scenarios(pm.compensator(zc[:-1]), families)
        return [None if m is None else jnp.asarray(m) for m in st], st

    solver = optx.BFGS(rtol=1e-8, atol=1e-8)
    history = []

    def same_topology(zc, count0, keep):
        cnt, res = phase_counts(pm.compensator(zc[:-1]), families)
        return bool(np.all(np.isfinite(np.asarray(zc)))) and bool(
            np.all(same_count(cnt, count0) & res | ~keep)
        )

    stages = [float(m) for m in mu_schedule]
    n_exchange = 0
    while stages:
        mu = stages[0]
        ts_ = time.perf_counter()
        # scenarios whose loop is stable at the stage start must stay so (same count,
        # resolved); chance-constrained scenarios that are unstable are free to change
        counted, st = counted_at(z)
        count0, res0 = phase_counts(pm.compensator(z[:-1]), families)
        keep = res0 & np.concatenate(
            [np.ones(f.scenarios.n_scenarios, bool) if m is None else m
             for f, m in zip(families, st, strict=True)]
        )  # fmt: skip
        sol = optx.minimise(
            fn, solver, z, args=(jnp.asarray(mu), scens, counted), max_steps=max_steps,
            throw=False,
        )  # fmt: skip
        z_new, frac = sol.value, 1.0
        # non-smooth guard: back off towards the previous stage's point until no scenario's
        # Nyquist count has changed (see phase_counts); give up the stage if none works
        while not same_topology(z_new, count0, keep) and frac > 1e-3:
            frac *= 0.5
            z_new = z + frac * (sol.value - z)
        stop = frac <= 1e-3
        if not stop:
            z = z_new
        # grid exchange: the margin constraint must hold between the training points too
        added = [0] * len(families)
        if not stop and n_exchange < max_exchanges:
            families, added = exchange(pm.compensator(z[:-1]), families, req.ms)
            scens = [f.scenarios for f in families]
        c = {k: float(v) for k, v in cons(z, scens, counted_at(z)[0]).items()}
        rec = {"mu": float(mu), "steps": int(sol.stats["num_steps"]), "result": str(sol.result),
               "bandwidth_hz": float(np.exp(z[-1]) / TWO_PI), "constraints": c,
               "wall_s": time.perf_counter() - ts_, "step_fraction": 0.0 if stop else frac,
               "grid_added": added}  # fmt: skip
        history.append(rec)
        if progress:
            progress(rec)
        if stop:
            break
        if sum(added):
            n_exchange += 1  # repeat this stage on the enlarged grid
        else:
            stages.pop(0)
    x = np.asarray(z[:-1])
    c = {k: float(v) for k, v in cons(z, scens, counted_at(z)[0]).items()}
    return TuneResult(
        g=pm.compensator(x), g0=g0, x=x, x0=np.asarray(x_given),
        bandwidth_hz=float(np.exp(z[-1]) / TWO_PI), bandwidth0_hz=wb0 / TWO_PI,
        constraints=c, history=history, names=pm.names, requirements=req,
        wall_s=time.perf_counter() - t0, gain_backoff=alpha,
    )  # fmt: skip
