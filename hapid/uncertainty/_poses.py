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

import dataclasses
from typing import NamedTuple

import equinox as eqx
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._plain import jsonable
from ..control import Compensator
from ..defaults import FIT_BAND_HZ
from ..device import cu5
from ..experiment import Protocol, estimate_frf, periodic_run
from ..fit import FitStatus
from ..pipeline import control_fit
from ..verdict import Verdict
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


class PoseLoop(NamedTuple):
    """One controller's loop on one pose's true sampled plant (:func:`pose_study`).

    - ``stable``: the closed loop is stable.
    - ``gm_db``, ``pm_deg`` (dB, degrees), ``disk_margin``, ``disk_gm_db``, ``disk_pm_deg``
      (the disk margin α and its gain/phase margins, dB and degrees), ``iso_bandwidth_hz``
      (Hz), ``t_peak_db`` (peak of σ̄(T), dB): Python floats, NaN where undefined (bandwidth
      and peak of an unstable loop).
    - ``passed``: the robust check's requirements (stability, GM, PM) are met.
    """

    stable: bool
    gm_db: float
    pm_deg: float
    disk_margin: float
    disk_gm_db: float
    disk_pm_deg: float
    iso_bandwidth_hz: float
    t_peak_db: float
    passed: bool


class PoseRow(NamedTuple):
    """One pose of a :class:`PoseStudy`: the grip-point offset ``dx, dy, dz`` (m), the
    ``nominal`` (home-pose) controller's :class:`PoseLoop`, and with re-identification the
    ``reidentified`` controller's and its fit's ``fit_status`` (else ``None``)."""

    dx: float
    dy: float
    dz: float
    nominal: PoseLoop
    reidentified: PoseLoop | None = None
    fit_status: FitStatus | None = None

    def flat(self) -> dict:
        """The row as one flat dict: ``dx, dy, dz``, ``nominal_<field>`` for each field of
        :class:`PoseLoop`, then (re-identified) ``fit_status`` and ``reidentified_<field>``."""
        out = {"dx": self.dx, "dy": self.dy, "dz": self.dz}
        out |= {f"nominal_{k}": v for k, v in self.nominal._asdict().items()}
        if self.reidentified is not None:
            out["fit_status"] = self.fit_status
            out |= {f"reidentified_{k}": v for k, v in self.reidentified._asdict().items()}
        return out


@dataclasses.dataclass(frozen=True)
class PoseStudy:
    """Result of :func:`pose_study`: ``rows``, one :class:`PoseRow` per pose in the order of
    the offsets (also ``study[i]``, ``len(study)``, iteration).

    ``status`` (:class:`hapid.verdict.Verdict`): ``passed`` when the nominal (home-pose)
    controller passes its check at every pose, else ``failed``. The check is on each pose's
    true plant, so it is never "not established"; ``ok`` when passed.
    """

    rows: tuple[PoseRow, ...]

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i) -> PoseRow:
        return self.rows[i]

    def __iter__(self):
        return iter(self.rows)

    @property
    def status(self) -> Verdict:
        return Verdict.PASSED if all(r.nominal.passed for r in self.rows) else Verdict.FAILED

    @property
    def ok(self) -> bool:
        return self.status is Verdict.PASSED

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``n_poses``, ``nominal_passed`` (poses where
        the nominal controller passes) and ``rows`` (:meth:`PoseRow.flat`, NaN → ``None``)."""
        return jsonable({"status": self.status, "ok": self.ok, "n_poses": len(self.rows),
                         "nominal_passed": sum(bool(r.nominal.passed) for r in self.rows),
                         "rows": [r.flat() for r in self.rows]})  # fmt: skip


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
) -> PoseStudy:
    """Closed-loop metrics of the nominal and re-identified controllers at each pose.

    - ``device``: a :class:`hapid.device.ParallelDevice` at its home pose (default ``cu5()``).
    - ``offsets``: ``(dx, dy, dz)`` grip-point offsets in m (default: home and ±4 cm per axis;
      see :func:`pose_grid`).
    - ``g``: compensator (default the paper's); ``protocol``: experiment (default
      ``Protocol()``); ``fit_options``: for :func:`hapid.pipeline.control_fit` (default relative
      weights, 40 Hz).
    - ``nominal_model``: the home-pose model (default: identified here at home).
    - ``reidentify``: also identify a controller at each pose (the costly part).

    Returns a :class:`PoseStudy`: one :class:`PoseRow` per pose (``dx, dy, dz``, the
    ``nominal`` and optionally the ``reidentified`` controller's :class:`PoseLoop`, the fit's
    ``fit_status``), passed when the nominal controller passes at every pose.
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
        rep = robust_check(P, (nominal_model, g), omega, p_stable_required=1.0, metrics="all")
        row = PoseRow(dx, dy, dz, _loop(rep))
        if reidentify:
            res = identify(dev, protocol, noise_seed=noise_seed, **fit_options)
            rep = robust_check(P, (res.model, g), omega, p_stable_required=1.0, metrics="all")
            row = row._replace(reidentified=_loop(rep), fit_status=res.status)
        rows.append(row)
    return PoseStudy(tuple(rows))


def _loop(rep) -> PoseLoop:
    return PoseLoop(stable=bool(rep.stable[0]), passed=bool(rep.passed),
                    **{f: float(getattr(rep, f)[0]) for f in FIELDS})  # fmt: skip
