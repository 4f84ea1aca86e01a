"""The robust check of a controller: on loop draws conditioned on the measured FRF
(:func:`loop_gp_check`) and from files, as ``hapid robust`` runs it (:func:`robust_from_files`,
:func:`side_by_side`).

It composes the uncertainty layer (loop draws, :func:`hapid.uncertainty.robust_check`) with
the tuner's evidence (:mod:`hapid.tune._evidence`: the certificate on the measured FRF and the
small-gain bound above it), so it sits above both.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import pipeline
from ._constants import TWO_PI
from ._grids import continuous_grid, nyquist_grid
from ._plain import jsonable
from .control import Compensator
from .defaults import DRAWS, GM_DB, N_DRAWS, PM_DEG
from .device import preset
from .io import load_frf, load_model, load_samples, save_json
from .tune._evidence import certificate, evidence_from_frf
from .tune._response import g_response
from .uncertainty._cover import EvidenceCover
from .uncertainty._draws import LoopDraws, draws_from
from .uncertainty._loopgp import loop_gp_plants, measured_data
from .uncertainty._robust import FIELDS, device_plants, posterior_omega, robust_check
from .verdict import Verdict, combine


@dataclasses.dataclass(frozen=True)
class RobustResult:
    """Result of :func:`robust_from_files`: ``posterior`` (the
    :class:`~hapid.uncertainty.RobustReport` of the loop or parameter draws; its ``draws``
    says which) and ``device`` (that of the device's true plants, or ``None``).

    ``status`` (:class:`hapid.verdict.Verdict`): ``failed`` if a check failed, else ``not
    established`` if one is, else ``passed``."""

    posterior: object
    device: object = None

    @property
    def status(self) -> Verdict:
        return combine(r.status for r in (self.posterior, self.device) if r is not None)

    @property
    def ok(self) -> bool:
        return self.status is Verdict.PASSED

    def numbers(self) -> dict:
        """``{"posterior": …, "device": … | None}``: each report's ``numbers()`` (NaN kept),
        the content of ``hapid robust``'s JSON file."""
        return {"posterior": self.posterior.numbers(),
                "device": None if self.device is None else self.device.numbers()}  # fmt: skip

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, then :meth:`numbers`."""
        return jsonable({"status": self.status, "ok": self.ok} | self.numbers())


LOOP_N_FREQ = 1000
"""Points of :func:`loop_gp_check`'s analysis grid when none is given."""


def loop_gp_check(
    measured,
    model,
    g,
    *,
    n_draws: int = N_DRAWS,
    n_freq: int = LOOP_N_FREQ,
    seed: int = 0,
    gm_db: float = GM_DB,
    pm_deg: float = PM_DEG,
    p_stable_required: float = 0.95,
    metrics=(),
    ts: float | None = None,
):
    """The robust check on draws of the loop conditioned on the measured FRF.

    ``measured``: the FRF (:func:`measured_data` input: ``omega``, ``Z_H``, ``Z_T``, every
    measured frequency); ``model``: the nominal model the controller ``G = g Ẑ_T Ẑ_H⁻¹``
    inverts; ``g``: a :class:`hapid.control.Compensator`; ``ts`` (s): the sampling period the
    controller runs at (``None``: the continuous-time controller). ``n_draws`` plants
    ``Q_d P̂`` (:func:`loop_gp_plants`), each analysed by
    :func:`hapid.uncertainty.robust_check` — with ``ts=None`` the continuous controller on
    :func:`hapid._grids.continuous_grid` (``n_freq``); with ``ts`` the discretized controller
    (its phase lag included, the loop ``hapid analyze --device`` closes at that rate) on
    :func:`hapid._grids.nyquist_grid` (the draws are of the measured, sampled plant). Returns
    the :class:`~hapid.uncertainty.RobustReport` of the draws — its
    :attr:`~hapid.uncertainty.RobustReport.check` is ``passed`` only when the measured band
    covers the loop (:mod:`hapid.uncertainty._cover`) — whose
    :attr:`~hapid.uncertainty.RobustReport.draws` holds ``draws`` (``"loop_gp"``), the GP's
    ``ell``, ``eta``, ``sigma2``, ``measurement_noise`` (whether the draws condition on the FRF's
    element std, :func:`hapid.uncertainty.measured_noise_var`), the measured band
    ``measured_hz`` ``[f₁, f_e]``, the evidence figures of :class:`hapid.tune.Certificate` (``frf_min_sigma_I_plus_L``,
    ``beyond_loop_gain``, ``certified``), ``beyond_covered``, ``loop``, and the isotropic
    bandwidth as ``iso_bandwidth_nominal_hz`` (of the conditional-mean loop, the nominal
    estimate from the measured FRF; ``None`` if that loop is not stable) with the draws'
    5–95 % ``iso_bandwidth_interval_hz`` (stable draws). Its calibration on held-out devices:
    benchmarks/calibrate_robust.py, docs/robust-design.md.
    """

    source = LoopDraws(measured)
    data = measured_data(measured)
    gp = source.gp(model)
    kw = dict(gm_db=gm_db, pm_deg=pm_deg, p_stable_required=p_stable_required,
              max_samples=None, metrics=metrics)  # fmt: skip
    # the draws and, last, the conditional-mean loop (the nominal bandwidth): one batch
    omega = continuous_grid(n_freq) if ts is None else nyquist_grid(1.0 / ts, n_freq)
    S = int(n_draws)
    P = np.concatenate([source.plants(model, omega, S, seed, gp=gp),
                        loop_gp_plants(gp, model, omega, 1, seed, mean=True)])  # fmt: skip
    if ts is None:
        rep = robust_check(P, (model, g), omega, **kw)
        loop = "continuous-time controller"
    else:
        ctrl = pipeline.controller(model, g, ts=ts)
        rep = robust_check(P, np.asarray(ctrl.response(omega)), omega,
                           controller_rhp=int(ctrl.p_rhp), **kw)  # fmt: skip
        loop = f"controller sampled at {1.0 / ts:g} Hz"
    ev = evidence_from_frf(data, model, ts=ts)
    cert = certificate(ev, model, g)
    # where |g| m falls to κ for good: on the checked grid above the band
    wb = np.geomspace(ev.omega_e, float(omega[-1]), 800)
    over = np.abs(np.asarray(g_response(g, wb, ev.ts))) * ev.mismatch > ev.kappa + 1e-9
    clear = float("nan") if over[-1] else float(wb[np.nonzero(over)[0][-1] + 1] if over.any()
                                                 else wb[0]) / TWO_PI  # fmt: skip
    lo, hi = float(data["omega"][0] / TWO_PI), float(data["omega"][-1] / TWO_PI)
    cover = EvidenceCover((lo, hi), cert.beyond_loop_gain, float(ev.kappa), clear,
                          float(ev.g_max), loop,
                          tuple(float(x) for x in np.asarray(data["omega"]) / TWO_PI))  # fmt: skip
    nominal_bw = float(rep.iso_bandwidth_hz[-1]) if bool(rep.stable[-1]) else None
    keep = ("stable", "n_closed_loop_rhp", "nyquist_resolved", "gm_freq_hz", "pm_freq_hz") + FIELDS
    rep = dataclasses.replace(rep, cover=cover, loop=loop,
                              **{k: np.asarray(getattr(rep, k))[:S] for k in keep})  # fmt: skip
    bw = np.asarray(rep.iso_bandwidth_hz)[np.asarray(rep.stable, bool)]
    draws = {"draws": "loop_gp", "ell": gp.ell, "eta": gp.eta, "sigma2": gp.sigma2,
            "measurement_noise": "FRF element std" if gp.v is not None else "none (nugget only)",
            "measured_hz": [lo, hi], **cert.figures(), "beyond_covered": cover.beyond_covered,
            "loop": loop, "iso_bandwidth_nominal_hz": nominal_bw,
            "iso_bandwidth_interval_hz": [float(x) for x in np.quantile(bw, [0.05, 0.95])]
            if bw.size else None}  # fmt: skip
    return dataclasses.replace(rep, draws=draws)


def robust_from_files(
    samples_path,
    model_path,
    out_json=None,
    *,
    frf_path=None,
    draws: str = "auto",
    g=None,
    gm_db: float = GM_DB,
    pm_deg: float = PM_DEG,
    max_samples: int = N_DRAWS,
    device=None,
    n_subjects: int = 0,
    pose_offsets=(),
    metrics=(),
    seed: int = 0,
    ts: float | None = None,
    n_freq: int | None = None,
    progress=None,
) -> RobustResult:
    """Samples file and/or measured FRF + nominal model file → :class:`RobustResult` (and
    optional JSON file of its :meth:`~RobustResult.numbers`).

    The controller is ``g Ẑ_T Ẑ_H⁻¹`` of the model file (``g`` default the paper's). ``draws``:

    - ``"loop_gp"``: ``max_samples`` draws of the loop ``Q = P P̂⁻¹`` conditioned on the whole
      measured FRF (:func:`hapid.robust.loop_gp_check`) — the FRF of ``frf_path``, else
      the one a samples file from ``hapid posterior`` stores (``PosteriorSamples.measured``);
    - ``"params"``: the posterior samples' own second-order plants (at most ``max_samples``):
      parameter uncertainty only, not calibrated where the model class is wrong (delay,
      unmodeled modes: benchmarks/calibrate_robust.py);
    - ``"auto"`` (default): ``"loop_gp"`` when a measured FRF is known, else ``"params"``.

    With ``device`` (a preset name, e.g. ``"cu5"``, or a device), the device-based check (nominal device,
    ``pose_offsets`` (dx, dy, dz) m, ``n_subjects`` virtual subjects) is added as
    ``device``. ``metrics``: as :func:`robust_check` (``"all"``: also the disk margin and
    the peak of σ̄(T); default: verdict, bandwidth and loci margins only — the others are
    ``None``). The posterior report's ``draws`` says which family was checked (and for
    ``loop_gp`` the GP, the measured band and whether the loop gain above it is small enough
    for the draws to cover it). Every report's summary carries the three-valued ``verdict`` (``"passed"``, ``"failed"``, ``"not
    established"``) with its ``reason`` and ``remedy`` (:attr:`RobustReport.check`) and the
    ``loop`` it was checked on. ``ts`` (s): the rate the controller runs at for the loop
    draws (default: the device's with ``device``, else the continuous-time controller).
    ``n_freq``: points of the analysis grid (default: :func:`loop_gp_check`'s for loop draws,
    :func:`~hapid._grids.continuous_grid`'s for parameter draws); a denser grid resolves
    loci whose phase the default grid does not. ``progress``: a callable taking one line of
    text (``hapid robust`` prints it on stderr), told what the check is doing before each step.
    """

    say = progress if progress is not None else (lambda _line: None)
    if draws not in DRAWS:  # before any file is read
        raise ValueError(f"draws must be one of {DRAWS}, got {draws!r}")
    if n_freq is not None and int(n_freq) < 50:
        raise ValueError(f"n_freq must be at least 50 grid points, got {n_freq}")
    model = load_model(model_path)
    ps = None if samples_path is None else load_samples(samples_path, n=model.n)
    measured = load_frf(frf_path) if frf_path is not None else getattr(ps, "measured", None)
    source = draws_from(draws, samples=ps, measured=measured)
    g = Compensator.paper() if g is None else g
    if isinstance(source, LoopDraws):
        n_meas = np.shape(measured["Z_H"] if isinstance(measured, dict) else measured.Z_H)[-1]
        if n_meas != model.n:
            raise ValueError(
                f"the measured FRF is for n = {n_meas} rods, the model for n = {model.n}"
            )
        if ts is None and device is not None:
            ts = (preset(device) if isinstance(device, str) else device).ts
        n = LOOP_N_FREQ if n_freq is None else int(n_freq)
        say(f"{max_samples} loop draws conditioned on the measured FRF, each checked on {n} "
            "frequencies")  # fmt: skip
        post = loop_gp_check(measured, model, g, n_draws=max_samples, n_freq=n, seed=seed,
                             gm_db=gm_db, pm_deg=pm_deg, metrics=metrics, ts=ts)  # fmt: skip
    else:
        om = posterior_omega() if n_freq is None else posterior_omega(int(n_freq))
        say(f"at most {max_samples} parameter draws, each checked on {len(om)} frequencies")
        rep = robust_check(ps, (model, g), om, gm_db=gm_db, pm_deg=pm_deg,
                           max_samples=max_samples, metrics=metrics, seed=seed)  # fmt: skip
        post = dataclasses.replace(rep, loop="continuous-time controller, second-order parameter draws",
                                   uncovered=PARAMS_UNCOVERED,
                                   draws={"draws": "params", "note": PARAMS_NOTE})  # fmt: skip
    dev_rep = None
    if device is not None:
        dev = preset(device) if isinstance(device, str) else device
        poses = [dev.pose.moved(*o) for o in pose_offsets]
        # the sampled controller (as analyze/paper/tune close the loop with the device) on a
        # grid to fs/2, refined crossings: the nominal row is the single analysis's numbers

        omega = nyquist_grid(dev.fs_hz)
        say(f"the device's true plants ({1 + len(poses)} pose(s), {n_subjects} virtual subject(s))")
        labels, P = device_plants(dev, omega, poses=poses, n_subjects=n_subjects)
        ctrl = pipeline.controller(model, g, ts=dev.ts)
        rep = robust_check(P, np.asarray(ctrl.response(omega)), omega,
                           controller_rhp=int(ctrl.p_rhp), gm_db=gm_db, pm_deg=pm_deg,
                           labels=labels, metrics=metrics)  # fmt: skip
        dev_rep = dataclasses.replace(rep, loop=f"controller sampled at {dev.fs_hz:g} Hz, "
                                      "the device's true plants")  # fmt: skip
    out = RobustResult(post, dev_rep)
    if out_json is not None:
        save_json(out_json, out.numbers())
    return out


PARAMS_NOTE = (
    "second-order parameter draws: parameter uncertainty only; where the model class is wrong "
    "(delay, unmodeled modes) P(stable) does not track the true plant's verdict "
    "(benchmarks/calibrate_robust.py) — give the measured FRF for loop draws"
)


PARAMS_UNCOVERED = (
    "second-order parameter draws cover the model class's parameter uncertainty only, not a "
    "delay or modes the class lacks",
    "give the measured FRF (--frf, or a samples file from hapid posterior) for loop draws",
)


def side_by_side(results: dict) -> str:
    """Markdown table of robust-check results of several controllers (``{label:
    RobustResult}``): one row per controller and batch (posterior, device); "—": not computed
    (``metrics``)."""
    cols = [("P(stable)", "p_stable", "{:.3f}"), ("GM q05 dB", "gm_db_q05", "{:.2f}"),
            ("GM q50 dB", "gm_db_q50", "{:.2f}"), ("PM q05°", "pm_deg_q05", "{:.1f}"),
            ("PM q50°", "pm_deg_q50", "{:.1f}"), ("disk q05", "disk_margin_q05", "{:.3f}"),
            ("iso-bw q05 Hz", "iso_bandwidth_hz_q05", "{:.2f}"),
            ("iso-bw q50 Hz", "iso_bandwidth_hz_q50", "{:.2f}"),
            ("T peak q50 dB", "t_peak_db_q50", "{:.2f}"), ("verdict", "verdict", "{}")]  # fmt: skip
    lines = ["| controller | plants | n | " + " | ".join(c[0] for c in cols) + " |",
             "|" + "---|" * (3 + len(cols))]  # fmt: skip
    for label, res in results.items():
        for batch in ("posterior", "device"):
            sm = res.numbers().get(batch)
            if sm is None:
                continue
            vals = ["—" if sm[key] is None else fmt.format(sm[key]) for _, key, fmt in cols]
            lines.append(f"| {label} | {batch} | {sm['n']} | " + " | ".join(vals) + " |")
    return "\n".join(lines)
