"""Hand-position study: a controller identified at home vs one re-identified at each pose.

For each stylus pose of a grid (offsets of the grip point from the home pose), the device's
true sampled plant ``P(ω)`` at that pose is analysed in closed loop with

- the **nominal** controller ``G₀ = g Ẑ_T,0 Ẑ_H,0⁻¹`` identified once at the home pose, and
- a **re-identified** controller ``G_pose``: ``periodic_run → estimate_frf → fit → G`` (the
  control fit of ``hapid fit``: :func:`hapid.pipeline.control_fit`)
  at that pose (same protocol, fit options and g).

The paper's "future work": how far can the stylus move before the home-pose controller
loses isotropy or margins. Default grid: home and ±4 cm along each axis (7 poses), cheap.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..control import Compensator
from ..defaults import FIT_BAND_HZ
from ..device import cu5
from ..experiment import Protocol, estimate_frf, periodic_run
from ..pipeline import control_fit
from ._robust import FIELDS, _sampled_P, robust_check, robust_omega

DEFAULT_OFFSETS = (
    (0.0, 0.0, 0.0),
    (0.04, 0.0, 0.0), (-0.04, 0.0, 0.0),
    (0.0, 0.04, 0.0), (0.0, -0.04, 0.0),
    (0.0, 0.0, 0.04), (0.0, 0.0, -0.04),
)  # fmt: skip


def pose_grid(
    step: float = 0.04, axes: str = "xyz", full: bool = False
) -> list[tuple[float, float, float]]:
    """Offsets (m): home plus ``±step`` along each of ``axes``; ``full=True`` gives the whole
    3ⁿ grid ``{−step, 0, step}^axes`` instead."""
    if not (np.isfinite(step) and step > 0):
        raise ValueError(f"step must be > 0, got {step}")
    idx = ["xyz".index(a) for a in axes]
    if full:
        vals = (
            np.array(np.meshgrid(*([(-step, 0.0, step)] * len(idx)), indexing="ij"))
            .reshape(len(idx), -1)
            .T
        )
        out = []
        for v in vals:
            o = [0.0, 0.0, 0.0]
            for k, i in enumerate(idx):
                o[i] = float(v[k])
            out.append(tuple(o))
        return out
    out = [(0.0, 0.0, 0.0)]
    for i in idx:
        for sgn in (1.0, -1.0):
            o = [0.0, 0.0, 0.0]
            o[i] = sgn * step
            out.append(tuple(o))
    return out


def identify(device, protocol=None, *, noise_seed: int = 0, **fit_options):
    """``periodic_run → estimate_frf →`` the NLS fit for control use
    (:func:`hapid.pipeline.control_fit`: PSD-boundary refit included; ``fit_options``
    are its options, e.g. ``boundary_refit``, ``f_max_hz``, ``omega_c_hz``) on a device;
    returns the NLS result."""
    protocol = Protocol() if protocol is None else protocol
    frf = estimate_frf(periodic_run(device, protocol, noise_seed=noise_seed))
    return control_fit(frf, **fit_options).fit.result


def pose_study(
    device=None,
    offsets=DEFAULT_OFFSETS,
    *,
    g: Compensator | None = None,
    protocol=None,
    nominal_model=None,
    omega=None,
    noise_seed: int = 0,
    reidentify: bool = True,
    fit_options: dict | None = None,
) -> list[dict]:
    """Closed-loop metrics of the nominal and re-identified controllers at each pose.

    - ``device``: a :class:`hapid.device.ParallelDevice` at its home pose (default ``cu5()``).
    - ``offsets``: ``(dx, dy, dz)`` grip-point offsets in m (default: home and ±4 cm per axis;
      see :func:`pose_grid`).
    - ``g``: compensator (default the paper's); ``protocol``: experiment (default
      ``Protocol()``); ``fit_options``: for :func:`hapid.pipeline.control_fit` (default relative
      weights, 40 Hz).
    - ``nominal_model``: the home-pose model (default: identified here at home).
    - ``reidentify``: also identify a controller at each pose (the costly part).

    Returns one dict per pose: ``dx, dy, dz`` and, for ``nominal`` and (optionally)
    ``reidentified``, ``{prefix}_stable``, ``{prefix}_{gm_db, pm_deg, disk_margin, …,
    iso_bandwidth_hz, t_peak_db}`` (NaN bandwidth/peak when unstable), plus ``fit_status``.
    """
    device = cu5() if device is None else device
    g = Compensator.paper() if g is None else g
    fit_options = {"weight": "relative", "f_max_hz": FIT_BAND_HZ} | dict(fit_options or {})
    omega = robust_omega() if omega is None else np.asarray(omega, dtype=float)
    offsets = [tuple(float(v) for v in o) for o in offsets]
    if any(len(o) != 3 or not np.all(np.isfinite(o)) for o in offsets):
        raise ValueError("offsets must be finite (dx, dy, dz) triples in m")
    if nominal_model is None:
        nominal_model = (
            identify(device, protocol, noise_seed=noise_seed, **fit_options).raise_if_failed().model
        )

    rows = []
    for dx, dy, dz in offsets:
        dev = eqx.tree_at(lambda d: d.pose, device, device.pose.moved(dx, dy, dz))
        P = _sampled_P(dev, omega)[None]
        row = {"dx": dx, "dy": dy, "dz": dz}
        rep = robust_check(P, (nominal_model, g), omega, p_stable_required=1.0, metrics="all")
        row |= _row("nominal", rep)
        if reidentify:
            res = identify(dev, protocol, noise_seed=noise_seed, **fit_options)
            row["fit_status"] = res.status
            rep = robust_check(P, (res.model, g), omega, p_stable_required=1.0, metrics="all")
            row |= _row("reidentified", rep)
        rows.append(row)
    return rows


def _row(prefix, rep):
    out = {f"{prefix}_stable": bool(rep.stable[0])}
    for f in FIELDS:
        out[f"{prefix}_{f}"] = float(getattr(rep, f)[0])
    out[f"{prefix}_passed"] = bool(rep.passed)
    return out
