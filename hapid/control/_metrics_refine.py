"""The refinement pass of :func:`~hapid.control.loop_metrics`: the sequential steps (Illinois,
Newton, multisection) on a handful of small matrices per asked metric, from the grid pass's
tasks. On its own its cost is the per-step overhead, which a caller with many loops
(``robust_check``) shares by running it once, vmapped, over all of them (:func:`refine_many`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .. import _config  # noqa: F401  (float64)
from ._margins import _DB, disk_margin_from_peak
from ._metrics_local import _Local
from ._metrics_loci import _loci_refined, _loci_select
from ._metrics_sigma import _peaks, _threshold_crossing
from ._metrics_spec import _SCALARS, ISO_THRESHOLD, TWO_PI, MetricsSpec


def refine_pass(out, tasks, L_fn, spec: MetricsSpec):
    """The refined metrics from :func:`grid_pass`'s ``(out, tasks)``: a dict of every
    :class:`LoopMetrics` field. Pure, jit/vmap-able; ``L_fn`` as :func:`loop_metrics`."""
    kern = spec.kernels
    stable = out["stable"]
    nan = jnp.full(jnp.shape(stable), jnp.nan)
    res = dict(out)
    for name in _SCALARS[5:]:
        res[name] = nan
    if spec.margins:
        t = tasks["margins"]
        loci = tasks.get("loci")  # (t, λ) refined by the caller (many loops at once), or here
        (g, gw), (p, pw) = _loci_select(t, *(loci or _loci_refined(t, L_fn)))
        res.update(gm_db=g, gm_freq_hz=gw / TWO_PI, pm_deg=p, pm_freq_hz=pw / TWO_PI)
    if spec.bandwidth:
        t = tasks["bandwidth"]
        w = _threshold_crossing(
            0, t["i"], t["j"], ISO_THRESHOLD, _Local(t["L"], t["lw"], L_fn), kern
        )
        bw = jnp.where(t["none"], jnp.inf, jnp.where(t["first"], 0.0, w))
        res["iso_bandwidth_hz"] = jnp.where(stable, bw / TWO_PI, nan)
    kinds = tuple(k for k, on in (("T", spec.t_peak), ("SmT", spec.disk)) if on)
    if kinds:
        t = tasks["peaks"]
        pk = dict(zip(kinds, _peaks(t, kinds, _Local(t["L"], t["lw"], L_fn), kern), strict=True))
    if spec.t_peak:
        v, w = pk["T"]
        res["t_peak_db"] = jnp.where(stable, _DB * jnp.log(v), nan)
        res["t_peak_hz"] = jnp.where(stable, w / TWO_PI, nan)
    if spec.disk:
        v, _ = pk["SmT"]
        res["disk_margin"] = jnp.where(stable, 2.0 / v, 0.0)
        dm = disk_margin_from_peak(v)
        res["disk_gm_db"] = jnp.where(stable, dm.disk_gm_db, 0.0)
        res["disk_pm_deg"] = jnp.where(stable, dm.disk_pm_deg, 0.0)
    if spec.literal:
        t = tasks["literal"]
        w = _threshold_crossing(
            0, t["i"], t["j"], ISO_THRESHOLD, _Local(t["L"], t["lw"], L_fn), kern
        )
        lit = jnp.where(t["none"], 0.0, jnp.where(t["last"], jnp.inf, w))
        res["iso_bandwidth_literal_hz"] = jnp.where(stable, lit / TWO_PI, nan)
    return res


def refine_many(out, tasks, L_fn, spec: MetricsSpec):
    """:func:`refine_pass` of many loops at once: ``out``/``tasks`` are :func:`grid_pass`'s
    results stacked on a leading axis ``(D, ...)``. Every loop's loci candidates are refined
    as one flat batch (its few slow candidates in compacted blocks), the rest vmapped; the
    sequential steps are paid once for the ``D`` loops. Returns the fields ``(D,)``."""
    if "margins" in tasks:
        m = tasks["margins"]
        D, C = m["k"].shape
        ts, lam = _loci_refined(jax.tree.map(lambda a: a.reshape((D * C,) + a.shape[2:]), m), L_fn)
        tasks = dict(tasks, loci=(ts.reshape(D, C), lam.reshape(D, C)))
    return jax.vmap(lambda o, t: refine_pass(o, t, L_fn, spec))(out, tasks)
