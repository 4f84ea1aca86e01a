"""Stages ``options → device``, ``device + protocol → experiment → frf``, and the analysis grid.

Options are scene-style dicts (Hz and SI; see :mod:`hapid.scene` for the keys). The device
variation (:func:`vary_device`: stylus move, virtual subject) and :func:`simulated_frf`
accept traced scalars, so a sweep can batch them with ``vmap``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._grids import log_grid_hz, nyquist_grid
from ..device import preset, virtual_subject
from ..experiment import (
    Protocol,
    estimate_frf,
    paper_frequencies,
    periodic_run,
    simulate_frf,
    time_domain_run,
)

MOVE_KEYS = ("dx", "dy", "dz", "dyaw", "dpitch", "droll")


def base_device(o: dict, fs_hz: float | None = None):
    """The preset device at home pose, before :func:`vary_device`: structural options
    ``preset``, ``light_damping``, ``extra_modes``, ``encoder``, ``delay_samples`` (actuator
    delay, samples) and ``rod_compliance`` (the chain's compliance factor) — the last two
    ``None`` or absent: the preset's own. ``fs_hz``: the sampling rate (Hz; default the
    preset's). Every preset takes every option."""
    kw = {"extra_modes": bool(o.get("extra_modes", True)),
          "light_damping": bool(o.get("light_damping", False)),
          "encoder": o.get("encoder", "motor")}  # fmt: skip
    if o.get("delay_samples") is not None:
        kw["delay_samples"] = int(o["delay_samples"])
    if o.get("rod_compliance") is not None:
        kw["rod_compliance"] = float(o["rod_compliance"])
    if fs_hz is not None:
        kw["fs_hz"] = float(fs_hz)
    return preset(o["preset"], **kw)


def vary_device(dev, move=(0.0,) * 6, subject_seed=None):
    """``dev`` moved by ``move`` (dx, dy, dz m; dyaw, dpitch, droll rad) and, when
    ``subject_seed`` is not ``None`` and ≥ 0, held by a virtual subject drawn from it.
    Traced values allowed (a negative traced seed keeps the nominal hand)."""
    mv = [jnp.asarray(v, dtype=jnp.float64) for v in list(move) + [0.0] * (6 - len(move))]
    dev = eqx.tree_at(lambda d: d.pose, dev, dev.pose.moved(*mv))
    if subject_seed is None:
        return dev
    seed = jnp.asarray(subject_seed)
    # every preset's first three DOF are the translations the subject ranges describe
    subj = virtual_subject(jax.random.PRNGKey(jnp.maximum(seed, 0).astype(jnp.int32)), dev.hand, 3)
    hand = jax.tree_util.tree_map(lambda a, b: jnp.where(seed >= 0, a, b), subj, dev.hand)
    return eqx.tree_at(lambda d: d.hand, dev, hand)


def device(o: dict, fs_hz: float | None = None):
    """Stage ``options → device``: :func:`base_device` then :func:`vary_device` (the one
    builder of a simulated device from options: scenes and the CLI's ``--device`` options)."""
    seed = o.get("subject_seed")
    return vary_device(
        base_device(o, fs_hz), list(o.get("move", ())), None if seed is None else int(seed)
    )


def protocol(o: dict, fs_hz: float | None = None):
    """The :class:`hapid.experiment.Protocol` of scene-style options."""
    freqs = paper_frequencies() if o["freqs"] == "paper" else np.asarray(o["freqs"], dtype=float)
    kw = {} if fs_hz is None else {"fs_hz": float(fs_hz)}
    return Protocol(
        freq_hz=tuple(freqs), n_periods=int(o["periods"]), transient_periods=int(o["transient"]),
        pattern=o["pattern"], phases=o["phases"], amplitude=float(o["amplitude"]),
        seed=int(o["seed"]), force_noise=float(o["noise"]),
        position_noise=float(o["position_noise"]), encoder_resolution=float(o["encoder_res"]), **kw,
    )  # fmt: skip


def experiment(dev, prot, *, synthesis: str = "periodic", friction: bool = False):
    """Stage ``device + protocol → run`` (exact periodic steady state, or ``lax.scan`` time
    domain with optional Coulomb friction)."""
    if synthesis == "time_domain" or friction:
        return time_domain_run(dev, prot, friction=bool(friction))
    if synthesis != "periodic":
        raise ValueError(
            f"protocol.synthesis must be 'periodic' or 'time_domain', got {synthesis!r}"
        )
    return periodic_run(dev, prot)


def frf(run, **options):
    """Stage ``run → FRF`` (:func:`hapid.experiment.estimate_frf`)."""
    return estimate_frf(run, **options)


def simulated_frf(dev, prot, seed, *, noise=None, position_noise=None, periods=None):
    """Stages ``device + protocol → frf`` in one pure function
    (:func:`hapid.experiment.simulate_frf`: exact averaged-noise statistics, no quantization).
    ``seed`` and the overrides may be traced."""
    key = jax.random.PRNGKey(jnp.asarray(seed).astype(jnp.int32))
    return simulate_frf(
        dev, prot, key, force_noise=noise, position_noise=position_noise, n_periods=periods
    )


def analysis_grid(f_min_hz, n_freq: int, fs_hz: float | None = None, f_max_hz: float | None = None):
    """Analysis frequencies (rad/s, ``(n_freq,)``), log-spaced from ``f_min_hz``.

    Sampled loop (``fs_hz`` given): to just below the Nyquist frequency, plus fs/2 itself
    (the discrete contour ends there). Continuous loop: to ``f_max_hz``. ``f_min_hz`` may be
    traced."""
    if fs_hz is not None:
        return nyquist_grid(fs_hz, n_freq, f_min_hz)
    if f_max_hz is None:
        raise ValueError("analysis_grid: give fs_hz (sampled loop) or f_max_hz (continuous)")
    return log_grid_hz(f_min_hz, f_max_hz, n_freq)
