# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Robust-margin check of a fixed controller over a batch of plants.

The controller is designed once from the *nominal* model, ``G(jω) = g(jω) Ẑ_T Ẑ_H⁻¹``, and
held fixed. Every plant of a batch is then analysed with
:func:`hapid.control.loop_metrics` (``vmap``-ed, in chunks): generalized-Nyquist stability
verdict first, then gain/phase margins of the characteristic loci and the isotropic
bandwidth; the balanced disk margin and the peak of σ̄(T) only when asked (``metrics``).

Two kinds of batches, and what each covers:

- **posterior samples** (:class:`PosteriorSamples` or a batched :class:`ImpedanceModel`):
  each ``P̂_s = Ẑ_H,s Ẑ_T,s⁻¹`` is a continuous *second-order* model without delay. This
  covers **parameter uncertainty within the model class only** — not the actuator delay,
  the sampling, or the unmodeled mechanism/hand dynamics that the class cannot represent.
- **device variants** (:func:`device_plants`): the simulated device's true sampled plant
  ``device.sampled_P(ω)`` (ZOH, one-sample delay, extra modes) at other stylus poses and for
  other virtual subjects. This covers delay and unmodeled dynamics, for the simulated
  device's variation only.

Open-loop RHP poles (needed by the Nyquist count): the controller's are the CRHP roots of
det Ẑ_H of the nominal model (:func:`hapid.control.controller_unstable_poles`); a model
plant's are the roots of det Ẑ_T,s with ``Re > 0`` (none for PD matrices); a device's are 0
(passive mechanics).

What is computed. By default only what the verdict (:attr:`RobustReport.passed`) and the
summary need: the Nyquist verdict, the isotropic bandwidth (σ̄(T − I) crossing) and the loci
gain/phase margins. The balanced disk margin (``disk_margin``, ``disk_gm_db``,
``disk_pm_deg``) and the peak of σ̄(T) (``t_peak_db``) cost as much again (one cu5 draw,
1000 frequencies: ≈ 9 ms of ≈ 16 ms) and are computed only when asked:
``robust_check(..., metrics=("disk", "t_peak"))``. A field not computed is NaN in the
per-plant arrays, listed in :attr:`RobustReport.not_computed`, ``None`` in
:meth:`~RobustReport.summary` / :meth:`~RobustReport.rows`, and asking for its quantile
raises; :attr:`RobustReport.worst` then ranks on the computed fields.

The result, its summary statistics and the margin sign convention:
:mod:`hapid.uncertainty._robust_report`. The compute path (``vectorize``,
``chunk``): :mod:`hapid.uncertainty._robust_chunks`.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .. import _config, _distributed  # noqa: F401  (float64)
from .._grids import continuous_grid as posterior_omega
from .._grids import sampled_grid as robust_omega
from ..control import Compensator
from ..defaults import GM_DB, PM_DEG
from ..device import virtual_subject
from ..fit._pd import theta_to_model
from ..impedance import ImpedanceModel
from ..pipeline import controller as make_controller
from ..samples import PosteriorSamples
from ._robust_chunks import _analyze_chunk, _pad, _spec
from ._robust_report import FIELDS, METRICS, RobustReport

__all__ = [
    "FIELDS",
    "METRICS",
    "RobustReport",
    "controller_response",
    "DevicePlants",
    "device_plants",
    "posterior_omega",
    "robust_check",
    "robust_omega",
]


@eqx.filter_jit
def _model_plants(theta, scale, omega):
    def one(t):
        m = theta_to_model(t, scale)
        return _plant_and_poles(m, omega)

    return jax.vmap(one)(theta)


@eqx.filter_jit
def _models_plants(models, omega):
    return jax.vmap(lambda m: _plant_and_poles(m, omega))(models)


def _plant_and_poles(m: ImpedanceModel, omega):
    P = m.P(1j * omega)
    r = m.total.roots()
    n_rhp = jnp.sum(jnp.real(r) > 0) + jnp.sum(~jnp.isfinite(r))
    return P, n_rhp


def controller_response(controller, omega):
    """``(G (N, n, n), open-loop RHP poles of G)`` from ``(nominal model, g)`` or an array."""
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if isinstance(controller, tuple) and len(controller) == 2:
        model, g = controller
        if not isinstance(model, ImpedanceModel) or not isinstance(g, Compensator):
            raise ValueError(
                "controller must be (nominal ImpedanceModel, Compensator) or G (N, n, n)"
            )

        ctrl = make_controller(model, g)  # continuous inverse-model controller (hapid.pipeline)
        return ctrl.response(omega), int(ctrl.p_rhp)
    G = jnp.asarray(controller, dtype=jnp.complex128)
    if G.ndim != 3 or G.shape[0] != omega.shape[0] or G.shape[1] != G.shape[2]:
        raise ValueError(f"G must be ({omega.shape[0]}, n, n), got shape {G.shape}")
    return G, 0


def robust_check(
    plants,
    controller,
    omega=None,
    *,
    p_ol_rhp=None,
    controller_rhp: int | None = None,
    gm_db: float = GM_DB,
    pm_deg: float = PM_DEG,
    p_stable_required: float = 0.95,
    chunk: int = 250,
    max_samples: int | None = 1000,
    seed: int = 0,
    labels=None,
    vectorize: bool = False,
    metrics: tuple = (),
) -> RobustReport:
    """Analyse the loop of a fixed controller with every plant of a batch.

    - ``plants``: :class:`PosteriorSamples` (at most ``max_samples`` random draws, ``seed``),
      a batched :class:`ImpedanceModel` (leading axis S), or plant responses ``(S, N, n, n)``
      on ``omega`` (then ``p_ol_rhp`` — int or ``(S,)`` — gives their open-loop RHP poles,
      default 0).
    - ``controller``: ``(nominal_model, g)`` (G = g Ẑ_T Ẑ_H⁻¹, its RHP poles counted from
      the nominal model) or a response ``G (N, n, n)`` (pass ``controller_rhp`` if G has
      RHP poles).
    - ``omega``: grid in rad/s (default: :func:`posterior_omega`, 0.005 Hz – 5 kHz, for
      model plants; :func:`robust_omega`, 0.05–450 Hz, for sampled plant arrays).
    - ``gm_db``, ``pm_deg``, ``p_stable_required``: requirements for ``passed``.
    - ``chunk``: plants per vmapped batch (memory: chunk × N × n² complex per array).
    - Every plant is analysed by :func:`~hapid.control.loop_metrics`'s program (XLA kernels,
      refined crossings; :mod:`hapid.uncertainty._robust_chunks`).
    - ``vectorize``: ``False`` (default) runs the grid pass once per
      plant and the refinement vmapped over each chunk; ``True`` vmaps the whole analysis
      over each chunk (slower on CPU for large chunks).
    - ``metrics``: what to compute beyond the verdict, the isotropic bandwidth and the loci
      GM/PM (which ``passed`` uses): any of ``"disk"`` (balanced disk margin, its GM/PM) and
      ``"t_peak"`` (peak of σ̄(T)), or ``"all"``. Fields not asked for are NaN and listed in
      :attr:`RobustReport.not_computed` (module docstring, "What is computed").

    Returns a :class:`RobustReport`.
    """
    metrics = (
        tuple(METRICS)
        if metrics == "all"
        else ((metrics,) if isinstance(metrics, str) else tuple(metrics))
    )
    bad = [m for m in metrics if m not in METRICS]
    if bad:
        raise ValueError(
            f"robust_check: metrics must be among {tuple(METRICS)} or 'all', got {bad}"
        )
    spec = _spec(metrics)
    computed = tuple(
        f for f in FIELDS if not any(f in METRICS[k] for k in METRICS if k not in metrics)
    )
    if omega is None:
        omega = (
            posterior_omega()
            if isinstance(plants, PosteriorSamples | ImpedanceModel)
            else robust_omega()
        )
    omega = np.asarray(omega, dtype=float)
    if omega.ndim != 1 or np.any(np.diff(omega) <= 0) or np.any(omega <= 0):
        raise ValueError("omega must be a strictly increasing (N,) array of positive rad/s")
    om = jnp.asarray(omega)
    G, c_rhp = controller_response(controller, om)
    if controller_rhp is not None:
        c_rhp = int(controller_rhp)
    if isinstance(plants, PosteriorSamples):
        theta = plants.theta
        if max_samples is not None and theta.shape[0] > max_samples:
            idx = np.random.default_rng(seed).choice(theta.shape[0], max_samples, replace=False)
            theta = theta[np.sort(idx)]
        S = theta.shape[0]

        def get(i, j):
            th = _pad(jnp.asarray(theta[i:j]), min(chunk, S))
            return tuple(a[: j - i] for a in _model_plants(th, plants.scale, om))

    elif isinstance(plants, ImpedanceModel):
        if np.ndim(plants.hand.M) != 3:
            raise ValueError("robust_check: a batched ImpedanceModel (S, n, n) is required")
        S = int(np.shape(plants.hand.M)[0])
        get = lambda i, j: _models_plants(jax.tree.map(lambda a: a[i:j], plants), om)  # noqa: E731
    else:
        P = jnp.asarray(plants, dtype=jnp.complex128)
        if P.ndim != 4 or P.shape[1:] != G.shape:
            raise ValueError(f"plants must be (S, {G.shape[0]}, n, n) matching G, got {P.shape}")
        S = P.shape[0]
        pol = jnp.broadcast_to(jnp.asarray(0 if p_ol_rhp is None else p_ol_rhp), (S,))
        get = lambda i, j: (P[i:j], pol[i:j])  # noqa: E731
    if S == 0:
        raise ValueError("robust_check: no plants")
    if G.shape[-1] != (
        plants.n if isinstance(plants, PosteriorSamples | ImpedanceModel) else G.shape[-1]
    ):
        raise ValueError(
            f"controller is {G.shape[-1]}×{G.shape[-1]} but the plants have n = {plants.n}"
        )
    parts = []
    chunk = max(1, min(int(chunk), S))
    for i in _distributed.local_chunks(S, chunk):  # all chunks, or this process's block
        j = min(S, i + chunk)
        Pc, pc = get(i, j)  # (not `pol`: the array path's `get` reads that name)
        pc = jnp.asarray(pc, dtype=jnp.float64) + c_rhp
        r = _analyze_chunk(_pad(Pc, chunk), _pad(pc, chunk), G, om, vectorize, spec, j - i)
        parts.append({k: v[: j - i] for k, v in r.items()})
    res = _distributed.gather(parts)  # every process's chunks, in order (one process: concat)
    if labels is not None and len(labels) != S:
        raise ValueError(f"{len(labels)} labels for {S} plants")
    return RobustReport(
        **res,
        gm_req_db=float(gm_db),
        pm_req_deg=float(pm_deg),
        p_stable_required=float(p_stable_required),
        labels=None if labels is None else tuple(labels),
        computed=computed,
    )


@eqx.filter_jit
def _sampled_P(device, omega):
    return device.sampled_P(omega)


class DevicePlants(NamedTuple):
    """True sampled plants of a simulated device's variants (:func:`device_plants`).

    - ``labels``: one name per variant (``"nominal"``, ``"pose k: d = …"``, ``"subject k"``).
    - ``P``: ``(S, N, n, n)`` complex, the sampled plant of each variant on ``omega``.
    """

    labels: list[str]
    P: Array


def device_plants(
    device, omega=None, *, poses=(), n_subjects: int = 0, key=0, include_nominal: bool = True
) -> DevicePlants:
    """True sampled plants of a simulated device's variants: :class:`DevicePlants`
    ``(labels, P (S, N, n, n))``.

    - ``device``: a :class:`hapid.device.ParallelDevice` (e.g. ``cu5()``).
    - ``poses``: :class:`hapid.device.Pose` objects (other stylus poses, nominal subject).
    - ``n_subjects``: virtual subjects (:func:`hapid.device.virtual_subject`) at the device's
      pose, drawn from ``key`` (JAX key or int).
    - ``include_nominal``: the device itself first.

    Pass the result to :func:`robust_check` (``p_ol_rhp`` 0: passive mechanics).
    """
    omega = jnp.asarray(robust_omega() if omega is None else omega, dtype=jnp.float64)
    labels, Ps = [], []
    if include_nominal:
        labels.append("nominal")
        Ps.append(_sampled_P(device, omega))
    for k, pose in enumerate(poses):
        d = eqx.tree_at(lambda x: x.pose, device, pose)
        c = np.asarray(pose.center) - np.asarray(device.pose.center)
        labels.append(f"pose {k}: d = ({c[0]:+.3f}, {c[1]:+.3f}, {c[2]:+.3f}) m")
        Ps.append(_sampled_P(d, omega))
    if n_subjects:
        key = jax.random.PRNGKey(key) if isinstance(key, int) else key
        for k, sk in enumerate(jax.random.split(key, n_subjects)):
            d = eqx.tree_at(lambda x: x.hand, device, virtual_subject(sk, device.hand))
            labels.append(f"subject {k}")
            Ps.append(_sampled_P(d, omega))
    if not Ps:
        raise ValueError("device_plants: nothing selected (no nominal, poses or subjects)")
    return DevicePlants(labels, jnp.stack(Ps))
