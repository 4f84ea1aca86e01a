"""Batched sweeps over any numeric option of any stage: one compiled ``vmap`` per chunk.

``run_sweep(cfg, {"fit.f_max_hz": [...], "controller.notch_hz[0]": [...]}, estimator="nls")``
forms the Cartesian product of the values and evaluates, per configuration, the scene's chain
composed from :mod:`hapid.pipeline`: device (pose, virtual subject) → simulated FRF
(:func:`hapid.pipeline.simulated_frf`: exact averaged-noise statistics) → fit with the named
estimator and its options (``nls``: :func:`hapid.pipeline.control_fit`, the fit ``hapid fit``,
``hapid posterior`` and a scene make, PSD-boundary refit included unless the scene's
``fit.boundary_refit`` is false; the ``fit_refit`` column says where it happened) → inverse-model controller sampled at the device's rate → loop
metrics on the true sampled plant, with the pipeline's verdict rule (the same as a single
``hapid analyze``: Nyquist resolved per determinant and per locus, ``I + L`` nonsingular,
encirclements = −(RHP poles of plant and controller), the controller's own RHP poles —
which positizing can leave — included).

**A statistically equivalent stand-in, not the scene's experiment.** The sweep's FRF is
:func:`hapid.pipeline.simulated_frf`: the frequency-domain FRF with the averaged-noise
statistics of the scene's protocol, not the scene's time-domain experiment (no encoder
quantization, another noise draw). A sweep at a scene's own values therefore gives that
scene's numbers only up to the spread of the FRF estimate (paper scene, k = 0.85:
2.712 Hz against ``hapid paper``'s 2.73 Hz); :data:`STAND_IN_NOTE` says so in every sweep's
output.

``protocol.seed`` selects the noise realization (the multisine phases stay those of the
scene's protocol). Option names are the scene's ``section.key`` (list elements as ``section.key[i]``; the stylus
move also as ``device.dx`` … ``device.droll``). Most options enter the compiled function as
traced values (:data:`TRACED`): one compile serves all of them. The others
(:data:`STATIC`: grid sizes, the NLS step budget, the excitation amplitude, the device's
delay and rod compliance) change shapes
or Python-level structure; each distinct value gets its own compile. The batch is split in
equal chunks (the last padded) for a progress bar, each chunk sharded over the JAX devices
when there are several (``XLA_FLAGS=--xla_force_host_platform_device_count=2`` emulates two),
and the chunks split over processes when run with ``jax.distributed`` (:mod:`hapid._distributed`,
``hapid sweep --processes N``): results identical to one process.
"""

from __future__ import annotations

import copy
import dataclasses
import enum
import itertools
import re
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from tqdm.auto import tqdm

from . import _config, _distributed, pipeline  # noqa: F401
from ._plain import jsonable
from .control import LoopStatus
from .fit import pphat_band_db
from .io import save_csv

STAND_IN_NOTE = (
    "note: the sweep's FRF is a statistically equivalent stand-in for the scene's experiment "
    "(frequency-domain FRF with the protocol's averaged-noise statistics: no encoder "
    "quantization, another noise draw), so at the scene's own values it reproduces the "
    "scene's numbers (hapid paper / run / analyze) only up to the FRF estimate's spread"
)

_MOVE = ("dx", "dy", "dz", "dyaw", "dpitch", "droll")
_NLS_NUMERIC = ("omega_c_hz", "f_max_hz", "rtol", "atol", "ftol", "patience", "blend_floor",
                "p_weight", "pd_eps", "init_floor")  # fmt: skip
TRACED = (
    tuple(f"device.{m}" for m in _MOVE) + ("device.move[i]", "device.subject_seed",
    "protocol.noise", "protocol.position_noise", "protocol.periods", "protocol.seed")
    + tuple(f"fit.{k}" for k in _NLS_NUMERIC)
    + ("controller.k", "controller.lag_zero_hz", "controller.lag_pole_hz", "controller.zeta_num",
       "controller.zeta_den", "controller.notch_hz[i]", "controller.lowpass_hz[i]",
       "analysis.f_min_hz", "analysis.band_hz")
)  # fmt: skip
STATIC = ("fit.max_steps", "analysis.n_freq", "protocol.amplitude", "device.delay_samples",
          "device.rod_compliance")  # fmt: skip
_STATIC_INT = ("fit.max_steps", "analysis.n_freq", "device.delay_samples")
_NO_EFFECT = {
    "protocol.transient": "the sweep's FRF is the exact periodic steady state (no transient)",
    "protocol.encoder_res": "the sweep's FRF has no encoder quantization",
    "controller.siso_gm_db": "the sweep closes the MIMO loop only",
    "controller.siso_pm_deg": "the sweep closes the MIMO loop only",
}
METRICS = ("stable", "n_encirclements", "p_ol", "nyquist_resolved", "iso_bandwidth_hz", "gm_db",
           "pm_deg", "t_peak_db", "t_peak_hz", "disk_margin", "pphat_min_db", "pphat_max_db",
           "crhp_hand", "crhp_total", "fit_ok", "fit_refit")  # fmt: skip
_BOOL_METRICS = ("stable", "nyquist_resolved", "fit_ok", "fit_refit")
ESTIMATOR_DEFAULT = "wls+positize"


def _point_status(stable, resolved):
    """:class:`~hapid.control.LoopStatus` of one configuration: ``STABLE``, else ``UNSTABLE``
    when the grid resolved the Nyquist count, else ``UNRESOLVED``."""
    if stable:
        return LoopStatus.STABLE
    return LoopStatus.UNSTABLE if resolved else LoopStatus.UNRESOLVED


@dataclasses.dataclass(frozen=True)
class SweepPoint:
    """One configuration of a sweep (:func:`run_single`, :meth:`SweepResult.point`).

    ``keys``: the varied option names; ``params``: ``(len(keys),)`` their values;
    ``metrics``: :data:`METRICS` name → value (``bool`` for ``stable``, ``nyquist_resolved``,
    ``fit_ok``, ``fit_refit``; ``float`` otherwise, NaN where undefined, e.g. the isotropic
    bandwidth of an unstable loop). ``status`` is the loop's
    :class:`~hapid.control.LoopStatus`: ``STABLE``, ``UNSTABLE`` or ``UNRESOLVED``."""

    keys: tuple[str, ...]
    params: np.ndarray
    metrics: dict

    @property
    def status(self) -> LoopStatus:
        return _point_status(self.metrics["stable"], self.metrics["nyquist_resolved"])

    @property
    def ok(self) -> bool:
        return self.status is LoopStatus.STABLE

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``params`` (option name → value), then the
        :data:`METRICS` (non-finite as ``None``)."""
        params = dict(zip(self.keys, self.params.tolist(), strict=True))
        return jsonable({"status": self.status, "ok": self.ok, "params": params} | self.metrics)


class SweepStatus(enum.StrEnum):
    """Outcome of :func:`run_sweep` (:class:`SweepResult`); ``ok`` means ``ALL_STABLE``."""

    ALL_STABLE = "all stable"
    SOME_STABLE = "some stable"
    NONE_STABLE = "none stable"


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """Result of :func:`run_sweep`: ``B`` configurations, the Cartesian product of the varied
    values in :func:`grid`'s order.

    ``keys``: the varied option names; ``params``: ``(B, len(keys))`` float, their values;
    ``metrics``: :data:`METRICS` name → ``(B,)`` array (bool for ``stable``,
    ``nyquist_resolved``, ``fit_ok``, ``fit_refit``; float otherwise, NaN where undefined);
    ``estimator``: the frf → model estimator. ``status``: ``ALL_STABLE``, ``SOME_STABLE`` or
    ``NONE_STABLE`` by the per-configuration verdict ``metrics["stable"]``."""

    keys: tuple[str, ...]
    params: np.ndarray
    metrics: dict
    estimator: str = ESTIMATOR_DEFAULT

    def __len__(self) -> int:
        return int(self.params.shape[0])

    @property
    def n_stable(self) -> int:
        """Number of configurations whose closed loop is stable."""
        return int(np.count_nonzero(self.metrics["stable"]))

    @property
    def status(self) -> SweepStatus:
        n = self.n_stable
        if n == len(self):
            return SweepStatus.ALL_STABLE
        return SweepStatus.SOME_STABLE if n else SweepStatus.NONE_STABLE

    @property
    def ok(self) -> bool:
        return self.status is SweepStatus.ALL_STABLE

    def point(self, i: int) -> SweepPoint:
        """Configuration ``i`` (``0 ≤ i < B``) as a :class:`SweepPoint`."""
        return SweepPoint(
            self.keys, self.params[i], _scalars({m: v[i] for m, v in self.metrics.items()})
        )

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``estimator``, ``n_configurations``,
        ``n_stable``, ``keys``, ``params`` (``B`` lists), ``metrics`` (name → ``B`` values,
        non-finite as ``None``) and ``note`` (:data:`STAND_IN_NOTE`)."""
        return jsonable({"status": self.status, "ok": self.ok, "estimator": self.estimator,
                         "n_configurations": len(self), "n_stable": self.n_stable,
                         "keys": list(self.keys), "params": self.params, "metrics": self.metrics,
                         "note": STAND_IN_NOTE})  # fmt: skip


def _columns(raw: dict) -> dict[str, np.ndarray]:
    """The :data:`METRICS` of ``raw`` as float arrays, the flags as bool arrays."""
    out = {m: np.asarray(raw[m], dtype=float) for m in METRICS}
    for m in _BOOL_METRICS:
        out[m] = out[m].astype(bool)
    return out


def _scalars(cols: dict) -> dict:
    """0-d columns as python ``bool`` (the flags) and ``float``."""
    return {m: bool(v) if m in _BOOL_METRICS else float(v) for m, v in cols.items()}


def _parse(key: str) -> tuple[str, str, int | None]:
    m = re.fullmatch(r"(\w+)\.(\w+)(?:\[(\d+)\])?", key)
    if not m:
        raise ValueError(f"bad option name {key!r}; expected section.key or section.key[i]")
    sec, k, i = m.group(1), m.group(2), m.group(3)
    if sec == "device" and k in _MOVE:
        return "device", "move", _MOVE.index(k)
    return sec, k, None if i is None else int(i)


def _pattern(key: str) -> str:
    sec, k, i = _parse(key)
    if sec == "device" and k == "move" and "[" not in key:
        return key  # device.dx … device.droll
    return f"{sec}.{k}" + ("" if i is None else "[i]")


def classify(key: str, cfg: dict, estimator: str) -> str:
    """``"traced"`` or ``"static"`` for a sweepable option; ``ValueError`` naming what is
    sweepable otherwise."""
    sec, k, i = _parse(key)
    if sec not in cfg or k not in cfg[sec]:
        raise ValueError(
            f"cannot sweep {key!r}: unknown option; sweepable: {', '.join(TRACED + STATIC)}"
        )
    if key in _NO_EFFECT:
        raise ValueError(f"cannot sweep {key!r}: {_NO_EFFECT[key]}")
    if sec == "fit" and not estimator.startswith("nls") and k != "omega_c_hz":
        raise ValueError(f"cannot sweep {key!r}: not an option of estimator {estimator!r}")
    if i is not None:
        seq = cfg[sec][k]
        if not isinstance(seq, list | tuple) or i >= len(seq):
            raise ValueError(
                f"cannot sweep {key!r}: {sec}.{k} has {len(seq) if isinstance(seq, list | tuple) else 'no'} elements"
            )
    p = _pattern(key)
    if p in TRACED:
        return "traced"
    if p in STATIC:
        return "static"
    raise ValueError(f"cannot sweep {key!r}; sweepable options: {', '.join(TRACED + STATIC)}")


def _set(cfg: dict, key: str, value) -> None:
    sec, k, i = _parse(key)
    if i is None:
        cfg[sec][k] = value
    else:
        seq = list(cfg[sec][k]) + [0.0] * max(0, i + 1 - len(cfg[sec][k]))
        seq[i] = value
        cfg[sec][k] = seq


def _fit_options(fo: dict, estimator: str) -> dict:
    if estimator.startswith("nls"):
        keys = ("weight", "solver", "max_steps") + _NLS_NUMERIC
        return {k: fo[k] for k in keys}
    return {"omega_c_hz": fo["omega_c_hz"]}


def point_fn(cfg: dict, keys: tuple[str, ...], estimator: str = ESTIMATOR_DEFAULT):
    """Pure function ``params (len(keys),) → metrics`` (dict of 0-d arrays) for one
    configuration of ``cfg`` with the traced options ``keys`` set from ``params``."""
    cfg = copy.deepcopy(cfg)
    if cfg["device"]["subject_seed"] is None and "device.subject_seed" in keys:
        cfg["device"]["subject_seed"] = -1.0
    base_dev = pipeline.base_device(cfg["device"])
    prot = pipeline.protocol(cfg["protocol"])
    n_freq = int(cfg["analysis"]["n_freq"])
    fs, ts = float(base_dev.fs_hz), float(base_dev.ts)
    fit_static = {k: cfg["fit"][k] for k in ("weight", "solver")} | {
        "max_steps": int(cfg["fit"]["max_steps"])
    }
    refit_on = bool(cfg["fit"].get("boundary_refit", True))

    def point(params):
        c = copy.deepcopy(cfg)
        for j, k in enumerate(keys):
            _set(c, k, params[j])
        d, p = c["device"], c["protocol"]
        dev = pipeline.vary_device(base_dev, d["move"], d["subject_seed"])
        frf = pipeline.simulated_frf(dev, prot, p["seed"], noise=p["noise"], position_noise=p["position_noise"],
                                     periods=p["periods"])  # fmt: skip
        fo = _fit_options(c["fit"] | fit_static, estimator)
        if estimator == "nls":  # the one NLS fit for control use, boundary refit included
            cf = pipeline.control_fit(frf, boundary_refit=refit_on, **fo)
            f, refit = cf.fit, cf.refitted
        else:
            f, refit = pipeline.fit(frf, estimator, **fo), jnp.asarray(False)
        omega = pipeline.analysis_grid(c["analysis"]["f_min_hz"], n_freq, fs)
        ctrl = pipeline.controller(f.model, pipeline.compensator(c["controller"]), ts=ts)
        rep = pipeline.loop(ctrl, pipeline.device_plant(dev, omega), pipeline.SPEC_SWEEP)
        out = {k: getattr(rep, k) for k in ("stable", "n_encirclements", "nyquist_resolved", "iso_bandwidth_hz",
                                            "gm_db", "pm_deg", "t_peak_db", "t_peak_hz", "disk_margin")}  # fmt: skip
        out["p_ol"] = jnp.asarray(ctrl.p_rhp)
        out["pphat_min_db"], out["pphat_max_db"] = pphat_band_db(
            dev.sampled_P(frf.omega), f.model, frf.omega, c["analysis"]["band_hz"]
        )
        out["crhp_hand"], out["crhp_total"], out["fit_ok"] = f.crhp_hand, f.crhp_total, f.ok
        out["fit_refit"] = refit
        return out

    return point


class SweepGrid(NamedTuple):
    """The points of a sweep (:func:`grid`): ``keys`` the varied options (``section.name``)
    and ``values`` ``(B, len(keys))`` float, one row per point."""

    keys: tuple[str, ...]
    values: np.ndarray


def grid(vary: dict[str, list]) -> SweepGrid:
    """Cartesian product of the varied values (:class:`SweepGrid`). Raises ``ValueError``
    for an option with no values or a non-finite value."""
    for k, vals in vary.items():
        if len(vals) == 0:
            raise ValueError(f"no values given for {k}")
    keys = tuple(vary)
    rows = np.array(list(itertools.product(*[np.asarray(v, dtype=float) for v in vary.values()])))
    if not np.all(np.isfinite(rows)):
        raise ValueError("sweep values must be finite numbers")
    return SweepGrid(keys, rows)


_INTEGER = {
    "protocol.periods": 1,
    "analysis.n_freq": 3,
    "fit.max_steps": 1,
    "fit.patience": 1,
    "protocol.seed": 0,
    "device.subject_seed": -1,
    "device.delay_samples": 0,
}  # name → smallest allowed value
_POSITIVE = ("protocol.amplitude", "device.rod_compliance")
_NONNEGATIVE = ("protocol.noise", "protocol.position_noise", "fit.pd_eps", "fit.blend_floor",
                "controller.zeta_num")  # fmt: skip


def _check_values(keys, rows):
    """Every value in range before any work (``ValueError`` naming the option and value)."""
    for j, k in enumerate(keys):
        v = rows[:, j]
        sec, name, _ = _parse(k)
        if k in _INTEGER:
            lo = _INTEGER[k]
            if np.any(v != np.round(v)) or np.any(v < lo):
                raise ValueError(
                    f"{k} must be an integer ≥ {lo}, got {v[(v != np.round(v)) | (v < lo)][0]:g}"
                )
        elif k in _NONNEGATIVE:
            if np.any(v < 0):
                raise ValueError(f"{k} must be ≥ 0, got {v.min():g}")
        elif sec in ("fit", "controller", "analysis") or k in _POSITIVE:
            if np.any(v <= 0):
                raise ValueError(f"{k} must be > 0, got {v.min():g}")


def run_sweep(cfg: dict, vary: dict[str, list], *, chunk: int = 64, progress: bool = True,
              estimator: str = ESTIMATOR_DEFAULT) -> SweepResult:  # fmt: skip
    """Evaluate every configuration of ``vary`` (option name → values, see :func:`grid`) on
    the scene config ``cfg``; returns a :class:`SweepResult`. Raises ``ValueError`` for an
    unknown estimator, a bad ``chunk``, an option that cannot be swept (:func:`classify`) or
    a value out of range.

    One compiled ``vmap`` per chunk and per distinct combination of static values. Under
    ``jax.distributed`` (:func:`hapid._distributed.initialize`) each process runs a contiguous
    block of the chunks and every process returns the whole result, identical to one process."""
    if estimator not in pipeline.ESTIMATORS:
        raise ValueError(
            f"unknown estimator {estimator!r}; known: {', '.join(sorted(pipeline.ESTIMATORS))}"
        )
    if not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    keys, rows = grid(vary)
    kinds = [classify(k, cfg, estimator) for k in keys]
    _check_values(keys, rows)
    traced = tuple(k for k, c in zip(keys, kinds, strict=True) if c == "traced")
    tcols = [j for j, c in enumerate(kinds) if c == "traced"]
    scols = [j for j, c in enumerate(kinds) if c == "static"]
    B = rows.shape[0]
    ndev = jax.local_device_count()  # this process's devices (jax.distributed: each has its own)
    chunk = max(ndev, min(chunk, B))
    chunk += (-chunk) % ndev
    sharding = None
    if ndev > 1:
        sharding = NamedSharding(Mesh(np.array(jax.local_devices()), ("b",)), PartitionSpec("b"))
    groups: dict[tuple, list[int]] = {}
    for i in range(B):
        groups.setdefault(tuple(rows[i, scols]), []).append(i)
    # the one-process plan: (static values, row indices, offset) per chunk; with several
    # processes (hapid._distributed) each runs a contiguous block of it, results gathered
    tasks = [(sv, idx, s) for sv, idx in groups.items() for s in range(0, len(idx), chunk)]
    mine = [tasks[t] for t in _distributed.block(len(tasks))]
    bar = None
    if progress and _distributed.is_main():
        procs = _distributed.process_count()
        bar = tqdm(total=len(mine), desc=f"sweep ({B} configurations, {len(groups)} compile(s), {ndev} device(s)"
                   + (f", {procs} processes" if procs > 1 else "") + ")", unit="chunk")  # fmt: skip
    fns: dict[tuple, object] = {}
    parts = []
    for svals, idx, s in mine:
        if svals not in fns:
            c = _with_options(cfg, [keys[j] for j in scols], svals)
            fns[svals] = jax.jit(jax.vmap(point_fn(c, traced, estimator)))
        sub = rows[np.ix_(idx, tcols)] if tcols else np.zeros((len(idx), 0))
        part = sub[s : s + chunk]
        pad = chunk - part.shape[0]
        x = np.concatenate([part, np.repeat(part[-1:], pad, axis=0)]) if pad else part
        x = jnp.asarray(x)
        if sharding is not None:
            x = jax.device_put(x, sharding)
        res = fns[svals](x)
        parts.append({m: np.asarray(res[m], dtype=float)[: part.shape[0]] for m in METRICS})
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    res = _distributed.gather(parts)
    order = np.concatenate([np.asarray(idx[s : s + chunk], dtype=int) for _, idx, s in tasks])
    out = {m: np.empty(B, dtype=float) for m in METRICS}
    for m in METRICS:
        out[m][order] = res[m]
    return SweepResult(keys, rows, _columns(out), estimator)


def _with_options(cfg: dict, keys, values) -> dict:
    """A copy of ``cfg`` with each option ``keys[j]`` set to ``values[j]`` (an int for the
    integer options, else a float)."""
    c = copy.deepcopy(cfg)
    for k, v in zip(keys, values, strict=True):
        _set(c, k, int(v) if k in _STATIC_INT else float(v))
    return c


def run_single(cfg: dict, keys, params, estimator: str = ESTIMATOR_DEFAULT) -> SweepPoint:
    """One configuration, unbatched, through the same stages as :func:`run_sweep` (``cfg``
    with the options ``keys`` set to ``params``); returns a :class:`SweepPoint`. The same
    program as one row of the sweep: static options set in the config, traced ones passed
    as arguments (so ``protocol.seed`` selects the noise draw and keeps the config's
    multisine phases, as in the sweep)."""
    kinds = [classify(k, cfg, estimator) for k in keys]
    traced = tuple(k for k, kind in zip(keys, kinds, strict=True) if kind == "traced")
    x = [float(v) for v, kind in zip(params, kinds, strict=True) if kind == "traced"]
    static = [(k, v) for k, v, kind in zip(keys, params, kinds, strict=True) if kind == "static"]
    c = _with_options(cfg, [k for k, _ in static], [v for _, v in static])  # as run_sweep
    fn = jax.jit(point_fn(c, traced, estimator))
    cols = _columns({k: np.asarray(v) for k, v in fn(jnp.asarray(x, dtype=float)).items()})
    return SweepPoint(tuple(keys), np.asarray(params, dtype=float), _scalars(cols))


def write_csv(path, result: SweepResult) -> Path:
    """The sweep table of ``result`` (one row per configuration: varied options, then
    :data:`METRICS`) as CSV; returns the path."""
    rows, metrics = result.params, result.metrics
    table = ([f"{v:g}" for v in rows[i]] + [f"{float(metrics[m][i]):.6g}" for m in METRICS]
             for i in range(rows.shape[0]))  # fmt: skip
    return save_csv(path, list(result.keys) + list(METRICS), table)


def plot_sweep(result: SweepResult, path) -> Path:
    """Iso-bandwidth and P·P̂⁻¹ band of ``result`` against the first varied option (others
    as colours), saved to ``path``; returns the path."""
    from . import plot  # local: CLI start-up (matplotlib)

    fig, _ = plot.sweep(result.keys, result.params, result.metrics)
    plot.save(fig, path)
    return Path(path)
