"""Batched hyperparameter sweeps: one compiled function ``vmap``-ped over configurations.

``run_sweep(cfg, {"protocol.noise": [...], "controller.k": [...]})`` forms the Cartesian
product of the values and evaluates, per configuration, the scene's pipeline in pure JAX:
device (pose, virtual subject) → simulated FRF (``simulate_frf``: exact averaged-noise
statistics) → the paper's WLS + positize fit → discretized inverse-model controller → loop
metrics on the true sampled plant. The batch is split in equal chunks (one compile serves
all of them; the last chunk is padded) for a progress bar, and each chunk is sharded over
the JAX devices when there are several (``XLA_FLAGS=--xla_force_host_platform_device_count=2``
emulates two on a CPU).

Sweepable options (numeric): ``fit.omega_c_hz``, ``protocol.noise``,
``protocol.position_noise``, ``protocol.periods``, ``protocol.seed`` (noise realization),
``controller.k``, ``device.subject_seed``, ``device.dx``, ``device.dy``, ``device.dz`` (m).

Loop metrics avoid eigen-decompositions (the characteristic loci): stability from the
winding of det(I + L), isotropic bandwidth and peak of T from singular values, the
conservative disk margin from σ̄(S − T). GM/PM per configuration: run the scene.
"""

from __future__ import annotations

import csv
import itertools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import _config  # noqa: F401
from ._constants import TWO_PI
from ._linalg import svdvals

SWEEPABLE = ("fit.omega_c_hz", "protocol.noise", "protocol.position_noise", "protocol.periods",
             "protocol.seed", "controller.k", "device.subject_seed", "device.dx", "device.dy",
             "device.dz")  # fmt: skip
METRICS = ("pphat_min_db", "pphat_max_db", "stable", "iso_bandwidth_hz", "t_peak_db",
           "disk_margin")  # fmt: skip


def loop_metrics(P, G, omega, band_mask=None):
    """Eigen-free loop metrics (jittable): dict of 0-d arrays (frequencies in Hz)."""
    from .control import ISO_THRESHOLD, isotropic_bandwidth, loop_matrices, nyquist_encirclements

    L, S, T = loop_matrices(P, G)
    n = L.shape[-1]
    det = jnp.linalg.det(jnp.eye(n) + L)
    enc, _, resolved = nyquist_encirclements(det)
    stable = resolved & (enc == 0)
    sv = svdvals(T - jnp.eye(n))
    bw, _ = isotropic_bandwidth(sv, omega, ISO_THRESHOLD)
    svT = svdvals(T)[:, 0]
    svST = svdvals(S - T)[:, 0]
    nan = jnp.nan
    return {
        "stable": stable,
        "iso_bandwidth_hz": jnp.where(stable, bw / TWO_PI, nan),
        "t_peak_db": jnp.where(stable, 20 * jnp.log10(jnp.max(svT)), nan),
        "disk_margin": jnp.where(stable, 2.0 / jnp.max(svST), 0.0),
    }


def _point_fn(cfg: dict, keys: tuple[str, ...]):
    """Pure function ``params (len(keys),) → metrics`` for one configuration."""
    import equinox as eqx

    from .control import discretize_controller
    from .device import virtual_subject
    from .experiment import simulate_frf
    from .fit import positize, wls
    from .scene import _device, _protocol, analysis_grid, compensator

    base_dev = _device(cfg["device"])
    prot = _protocol(cfg["protocol"])
    g = compensator(cfg["controller"])
    omega = jnp.asarray(analysis_grid(cfg["analysis"], base_dev.fs_hz))
    band_hz = float(cfg["analysis"]["band_hz"])
    defaults = {
        "fit.omega_c_hz": float(cfg["fit"]["omega_c_hz"]),
        "protocol.noise": float(cfg["protocol"]["noise"]),
        "protocol.position_noise": float(cfg["protocol"]["position_noise"]),
        "protocol.periods": float(cfg["protocol"]["periods"]),
        "protocol.seed": float(cfg["protocol"]["seed"]),
        "controller.k": float(cfg["controller"]["k"]),
        "device.subject_seed": -1.0 if cfg["device"]["subject_seed"] is None else float(cfg["device"]["subject_seed"]),
        "device.dx": 0.0, "device.dy": 0.0, "device.dz": 0.0,
    }  # fmt: skip
    k0 = float(cfg["controller"]["k"])

    def point(params):
        p = dict(defaults)
        for i, k in enumerate(keys):
            p[k] = params[i]
        dev = eqx.tree_at(lambda d: d.pose, base_dev, base_dev.pose.moved(p["device.dx"], p["device.dy"], p["device.dz"]))
        if "device.subject_seed" in keys:
            seed = p["device.subject_seed"].astype(jnp.int32)
            subj = virtual_subject(jax.random.PRNGKey(seed), dev.hand, 3)
            hand = jax.tree_util.tree_map(lambda a, b: jnp.where(seed >= 0, a, b), subj, dev.hand)
            dev = eqx.tree_at(lambda d: d.hand, dev, hand)
        key = jax.random.PRNGKey(p["protocol.seed"].astype(jnp.int32) if "protocol.seed" in keys else int(p["protocol.seed"]))
        frf = simulate_frf(dev, prot, key, force_noise=p["protocol.noise"],
                           position_noise=p["protocol.position_noise"], n_periods=p["protocol.periods"])  # fmt: skip
        model = positize(wls(frf, omega_c=TWO_PI * p["fit.omega_c_hz"]))
        Pex = dev.sampled_P(frf.omega)
        Q = Pex @ model.P_inv(1j * frf.omega)
        db = 20 * jnp.log10(svdvals(Q))
        inband = (frf.omega <= TWO_PI * band_hz)[:, None]
        ctrl = discretize_controller(model, g, dev.ts)
        G = (p["controller.k"] / k0) * ctrl.at_omega(omega)
        out = loop_metrics(dev.sampled_P(omega), G, omega)
        out["pphat_min_db"] = jnp.min(jnp.where(inband, db, jnp.inf))
        out["pphat_max_db"] = jnp.max(jnp.where(inband, db, -jnp.inf))
        return out

    return point


def grid(vary: dict[str, list]) -> tuple[tuple[str, ...], np.ndarray]:
    """Cartesian product of the varied values: ``(keys, (B, len(keys)) float array)``."""
    for k, vals in vary.items():
        if k not in SWEEPABLE:
            raise ValueError(f"cannot sweep {k!r}; sweepable options: {', '.join(SWEEPABLE)}")
        if len(vals) == 0:
            raise ValueError(f"no values given for {k}")
    keys = tuple(vary)
    rows = np.array(list(itertools.product(*[np.asarray(v, dtype=float) for v in vary.values()])))
    if not np.all(np.isfinite(rows)):
        raise ValueError("sweep values must be finite numbers")
    return keys, rows


def run_sweep(cfg: dict, vary: dict[str, list], *, chunk: int = 64, progress: bool = True):
    """Evaluate every configuration; returns ``(keys, params (B, k), metrics dict of (B,))``."""
    keys, rows = grid(vary)
    fn = jax.jit(jax.vmap(_point_fn(cfg, keys)))
    B = rows.shape[0]
    ndev = jax.device_count()
    chunk = max(ndev, min(chunk, B))
    chunk += (-chunk) % ndev
    sharding = None
    if ndev > 1:
        from jax.sharding import Mesh, NamedSharding, PartitionSpec

        sharding = NamedSharding(Mesh(np.array(jax.devices()), ("b",)), PartitionSpec("b"))
    outs = []
    starts = range(0, B, chunk)
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, desc=f"sweep ({B} configurations, {ndev} device(s))", unit="chunk")
    for s in starts:
        part = rows[s : s + chunk]
        pad = chunk - part.shape[0]
        x = np.concatenate([part, np.repeat(part[-1:], pad, axis=0)]) if pad else part
        x = jnp.asarray(x)
        if sharding is not None:
            x = jax.device_put(x, sharding)
        res = fn(x)
        outs.append({k: np.asarray(v)[: part.shape[0]] for k, v in res.items()})
    metrics = {k: np.concatenate([o[k] for o in outs]) for k in METRICS}
    return keys, rows, metrics


def run_single(cfg: dict, keys, params) -> dict:
    """One configuration, unbatched (the reference a batched sweep must match)."""
    fn = jax.jit(_point_fn(cfg, tuple(keys)))
    return {k: np.asarray(v) for k, v in fn(jnp.asarray(params, dtype=float)).items()}


def write_csv(path, keys, rows, metrics) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(keys) + list(METRICS))
        for i in range(rows.shape[0]):
            w.writerow([f"{v:g}" for v in rows[i]] + [f"{float(metrics[m][i]):.6g}" for m in METRICS])
    return path


def plot_sweep(keys, rows, metrics, path) -> Path:
    """Iso-bandwidth and P·P̂⁻¹ band against the first varied option (others as colours)."""
    from . import plot

    fig, _ = plot.sweep(keys, rows, metrics)
    plot.save(fig, path)
    return Path(path)
