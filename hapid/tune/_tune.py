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
import enum
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from .._plain import jsonable
from ..control import Compensator, MetricsSpec, nyquist_encirclements, nyquist_verdict
from ..defaults import TUNE_TOL, TUNE_TOL_WORST
from ..verdict import Check
from ._exchange import exchange
from ._objective import Box, Requirements, aggregate, penalized, penalized_parts
from ._params import ParamMap
from ._progress import TuneProgress, note
from ._response import g_response


class TuneStatus(enum.StrEnum):
    """Outcome of :func:`tune` (:class:`TuneResult`); ``ok`` means ``FEASIBLE``."""

    FEASIBLE = "feasible"
    INFEASIBLE = "infeasible"
    UNSTABLE_ON_TRAINING = "unstable on training plants"


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """Outcome of :func:`tune`.

    ``g`` tuned compensator, ``g0`` the start; ``x``, ``x0`` their log-parameters;
    ``bandwidth_hz`` the claimed smooth robust bandwidth ω_b/2π at the end (``bandwidth0_hz``
    at the start); ``constraints`` the final CVaR constraint values (≤ 0 met, in log
    units); ``gain_backoff`` the factor on ``k`` the tuner started from (< 1 when ``g0``
    left training scenarios unstable, :func:`gain_backoff`); ``history`` one dict per μ stage (μ, steps, result, claimed bandwidth,
    constraints, wall time); ``names`` parameter names; ``requirements``; ``training`` and
    ``training0``: ``{family: (stable, required, total)}`` training scenarios whose closed
    loop is stable under ``g`` and ``g0`` by the analysis' Nyquist rule
    (:func:`training_verdict`); ``check``: the three-valued verdict of the design on the
    held-out evidence (:func:`hapid.tune._check.design_check`; ``None`` when not re-checked).
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
    training: dict = dataclasses.field(default_factory=dict)
    training0: dict = dataclasses.field(default_factory=dict)
    check: Check | None = None

    @property
    def feasible(self) -> bool:
        """Every smooth constraint met (to 1e-3 in log units) on the training scenarios."""
        return all(v <= 1e-3 for v in self.constraints.values())

    @property
    def stable_on_training(self) -> bool:
        """Enough training scenarios of every Nyquist-contour family stable under ``g`` (all
        of a strict family; a chance-constrained one's quantile) — :attr:`training`."""
        return all(st >= req for st, req, _ in self.training.values())

    @property
    def ok(self) -> bool:
        """The smooth constraints are met and every training loop is stable."""
        return self.feasible and self.stable_on_training

    @property
    def status(self) -> TuneStatus:
        """:class:`TuneStatus`: ``FEASIBLE`` (:attr:`ok`), ``INFEASIBLE`` (a smooth constraint
        not met) or ``UNSTABLE_ON_TRAINING``."""
        if self.ok:
            return TuneStatus.FEASIBLE
        return TuneStatus.INFEASIBLE if self.stable_on_training else TuneStatus.UNSTABLE_ON_TRAINING

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, claimed bandwidths (Hz), constraints,
        parameters, the training counts and, when re-checked, the check (``verdict``,
        ``reason``, ``remedy``, ``check``); non-finite numbers as ``None``."""
        return jsonable({"ok": self.ok, "status": self.status, "bandwidth_hz": float(self.bandwidth_hz),
                "training_stable": {k: list(v) for k, v in self.training.items()},
                "bandwidth0_hz": float(self.bandwidth0_hz), "gain_backoff": float(self.gain_backoff),
                "constraints": {k: float(v) for k, v in self.constraints.items()},
                "parameters": self.parameters(), "wall_s": float(self.wall_s)} | (
                    {} if self.check is None else {"verdict": self.check.verdict.value,
                    "reason": self.check.reason, "remedy": self.check.remedy, "check": self.check.name}))  # fmt: skip

    def parameters(self) -> list[dict]:
        """Rows ``{name, start, tuned}`` (frequencies in Hz)."""
        pm = ParamMap.from_template(self.g0)
        a, b = pm.describe(self.x0), pm.describe(self.x)
        return [{"name": n, "start": a[n], "tuned": b[n]} for n in pm.names]


def phase_counts(g: Compensator, families) -> tuple[np.ndarray, np.ndarray]:
    """Clockwise encirclements of 0 by ``det(I + g Q) = Π_i (1 + g λ_i)`` over the full
    Nyquist contour, per scenario, and whether the grid resolved them — the count of every
    loop analysis in hapid (:func:`hapid.control.nyquist_encirclements`), on the family's
    dense grid when it has one (:attr:`.Family.dense`).

    The closed-loop RHP-pole count of a scenario can only change when this count does (same
    open-loop poles): :func:`tune` uses it as the non-smooth guard that the smooth margin
    constraints cannot give — a BFGS step may jump a locus across −1 between iterates.
    Families whose grid is not a Nyquist contour (``Family.contour`` False: the measured
    FRF's points) are reported unresolved.
    """
    per = [_family_counts(g, f) for f in families]
    return np.concatenate([p[2] for p in per]), np.concatenate([p[3] for p in per])


def _family_counts(g: Compensator, f):
    """One family's Nyquist counts on the grid :func:`phase_counts` uses (the dense one when
    there is one): ``(scenarios, g(jω) (N,), encirclements (S,), resolved (S,), stable
    (S,))``. ``stable`` is THE stability rule of every analysis,
    :func:`hapid.control.nyquist_verdict`, with each scenario's open-loop RHP poles
    (``Scenarios.p_ol``: the plant's and the controller matrix part's): the tuner calls a
    loop stable exactly when :func:`hapid.pipeline.loop` would on the same grid."""
    sc = f.scenarios if f.dense is None else f.dense
    gam = np.asarray(g_response(g, sc.omega, sc.ts))
    one_plus = 1.0 + gam[None, :, None] * np.asarray(sc.lam)
    d = np.prod(one_plus, axis=-1)
    n_enc, _, res = (np.asarray(a) for a in _encirclements(jnp.asarray(d)))
    if not f.contour:
        res = np.zeros_like(res)
    singular = np.min(np.abs(one_plus), axis=(1, 2)) <= SINGULAR_RTOL
    stable = np.asarray(nyquist_verdict(n_enc, np.asarray(sc.p_ol), res, singular))
    return sc, gam, n_enc, res, stable


_encirclements = jax.jit(jax.vmap(nyquist_encirclements))
SINGULAR_RTOL = MetricsSpec().singular_rtol
"""``|1 + g λ_i|`` at or below this counts as a singular ``I + L`` (as the analysis)."""


def same_count(a, b):
    """Equal encirclement counts from two :func:`phase_counts` results."""
    return np.abs(np.asarray(a) - np.asarray(b)) < 0.5


def stable_scenarios(g: Compensator, families) -> list:
    """Per family, ``(S,)`` bool: is the closed loop of each scenario stable under ``g``
    (:func:`_family_counts`' verdict: resolved, and the encirclements equal to minus the
    open-loop RHP poles)? Only for families with ``quantile < 1`` (chance constraints); else
    ``None`` (all scenarios counted, as the strict guard assumes)."""
    return [None if f.quantile >= 1.0 else _family_counts(g, f)[4] for f in families]


def _start_ok(g: Compensator, families, ms: float | None = None) -> bool:
    """Does ``g`` leave no scenario of a strict family (``quantile`` 1) and at most ``K − 1``
    of a chance-constrained one unstable or unresolved (:func:`_family_counts`' verdict,
    that of the analysis)? With ``ms``: and with every locus outside the disc of radius
    ``1/ms`` around −1 (margins). Families that are not Nyquist contours (the measured FRF)
    are judged on the disc only. On the family's dense grid when it has one."""
    for f in families:
        sc, gam, _, _, stable = _family_counts(g, f)
        bad = ~stable if f.contour else np.zeros(sc.n_scenarios, bool)
        if ms is not None and f.margins:
            d = np.abs(1.0 + gam[None, :, None] * np.asarray(sc.lam)).min(axis=(1, 2))
            bad |= d < 1.0 / ms
        if np.sum(bad) > (0 if f.quantile >= 1.0 else f.k_worst() - 1):
            return False
    return True


def training_verdict(g: Compensator, families) -> dict:
    """``{family name: (stable, required, total)}`` for the families that are Nyquist
    contours: how many training scenarios ``g`` leaves stable by the analysis' rule
    (:func:`_family_counts`), and how many must be (all of a strict family; all but
    ``K − 1`` of a chance-constrained one, as the chance constraint counts them)."""
    out = {}
    for f in families:
        if f.contour:
            st = _family_counts(g, f)[4]
            req = st.size if f.quantile >= 1.0 else st.size - (f.k_worst() - 1)
            out[f.name] = (int(np.sum(st)), int(req), int(st.size))
    return out


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
    if _start_ok(g, families):
        return g, 1.0
    alpha = largest_gain(g, lambda gg: _start_ok(gg, families, ms), alpha_min, iters)
    if alpha is None:
        a_stable = largest_gain(g, lambda gg: _start_ok(gg, families), alpha_min, iters)
        if a_stable is None:
            return g, 1.0
        alpha = 0.5 * a_stable
    return scale_gain(g, alpha), alpha


def scale_gain(g: Compensator, alpha) -> Compensator:
    """``g`` with its gain ``k`` multiplied by ``alpha``."""
    return eqx.tree_at(lambda c: c.k, g, g.k * alpha)


def largest_gain(g: Compensator, pred, alpha_min: float = 1e-3, iters: int = 12) -> float | None:
    """Largest ``α`` in ``[alpha_min, 1)`` found by bisection in log α at which
    ``pred(scale_gain(g, α))`` holds (the last α it held at), ``None`` if it fails at
    ``alpha_min``. ``α = 1`` itself is not tried: callers check it first."""
    lo, hi = np.log(alpha_min), 0.0
    if not pred(scale_gain(g, alpha_min)):
        return None
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pred(scale_gain(g, np.exp(mid))) else (lo, mid)
    return float(np.exp(lo))


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
    tol: float = TUNE_TOL,
    tol_worst: float = TUNE_TOL_WORST,
) -> TuneResult:
    """Tune g's parameters (log coordinates) for the largest robust isotropic bandwidth.

    - ``families``: list of :class:`.Family` (scenario plants with a required quantile).
    - ``g0``: starting compensator, also fixing the structure (default the paper's g).
    - ``requirements``: :class:`.Requirements` (6 dB, 30°, threshold 0.293).
    - ``box``: soft box on the log-parameters (default :meth:`.Box.default` with frequencies
      up to ``f_max_hz``: 0.45·f_s for a sampled design, else a quarter of the grid's top).
    - ``mu_schedule``, ``max_steps``: continuation stages and BFGS steps per stage.
    - ``rho``: weight of ``‖x − x₀‖²`` (keeps flat directions near the start).
    - ``progress``: a :class:`.TuneProgress` (a bar over the stages), or a callable
      given each stage's history entry, or None.
    - ``tol``, ``tol_worst``: relative and absolute tolerance of each stage's BFGS solve when
      a family is chance-constrained (quantile < 1), and when every family is worst-case
      (:data:`hapid.defaults.TUNE_TOL`, :data:`hapid.defaults.TUNE_TOL_WORST`).
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
    note(progress, "checking the start g on the training plants")
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
    def cons(z, mu, sc, counted):  # (objective, constraints) at z
        return penalized_parts(z, mu, pm, rebuild(sc), req, box, x0, rho, counted)

    def counted_at(zc):
        st = stable_scenarios(pm.compensator(zc[:-1]), families)
        return [None if m is None else jnp.asarray(m) for m in st], st

    # sampled plants: stop early (the training draws' tail is not the plant's); worst-case
    # families: converge (defaults.TUNE_TOL, TUNE_TOL_WORST)
    stol = tol if any(f.quantile < 1.0 for f in families) else tol_worst
    solver = optx.BFGS(rtol=stol, atol=stol)
    history = []

    def same_topology(zc, count0, keep):
        cnt, res = phase_counts(pm.compensator(zc[:-1]), families)
        return bool(np.all(np.isfinite(np.asarray(zc)))) and bool(
            np.all(same_count(cnt, count0) & res | ~keep)
        )

    stages = [float(m) for m in mu_schedule]
    n_exchange, n_done = 0, 0
    mu = stages[0] if stages else 0.0
    report = progress if isinstance(progress, TuneProgress) else None
    while stages:
        mu = stages[0]
        if report is not None:
            report.stage(n_done, n_done + len(stages), mu)
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
        obj, c = cons(z, jnp.asarray(mu), scens, counted_at(z)[0])
        c = {k: float(v) for k, v in c.items()}
        rec = {"mu": float(mu), "steps": int(sol.stats["num_steps"]), "result": str(sol.result),
               "objective": float(obj),
               "bandwidth_hz": float(np.exp(z[-1]) / TWO_PI), "constraints": c,
               "wall_s": time.perf_counter() - ts_, "step_fraction": 0.0 if stop else frac,
               "grid_added": added}  # fmt: skip
        history.append(rec)
        n_done += 1
        if report is not None:
            report.stage_done(rec)
        elif progress:
            progress(rec)
        if stop:
            break
        if sum(added):
            n_exchange += 1  # repeat this stage on the enlarged grid
        else:
            stages.pop(0)
    x = np.asarray(z[:-1])
    c = {k: float(v) for k, v in cons(z, jnp.asarray(mu), scens, counted_at(z)[0])[1].items()}
    return TuneResult(
        g=pm.compensator(x), g0=g0, x=x, x0=np.asarray(x_given),
        bandwidth_hz=float(np.exp(z[-1]) / TWO_PI), bandwidth0_hz=wb0 / TWO_PI,
        constraints=c, history=history, names=pm.names, requirements=req,
        wall_s=time.perf_counter() - t0, gain_backoff=alpha,
        training=training_verdict(pm.compensator(x), families),
        training0=training_verdict(g0, families),
    )  # fmt: skip
