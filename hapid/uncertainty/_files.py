"""File-level helpers for the CLI (``hapid posterior``, ``hapid robust``): plain functions."""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..defaults import FIT_BAND_HZ, GM_DB, PM_DEG


def posterior_from_files(
    frf_path,
    out_path,
    *,
    method: str = "emcee",
    n_samples: int = 4000,
    n_steps: int | None = None,
    seed: int = 0,
    progress: bool = True,
    backend_path=None,
    fit_options: dict | None = None,
    posterior_options: dict | None = None,
    sampler_options: dict | None = None,
    fix_boundary: bool = True,
    boundary_refit: bool = True,
):
    """FRF file → NLS fit (start point) → posterior samples file (``.npz``).

    The fit is ``hapid fit``'s, made by the same call: the FRF cut to ``0–f_max_hz`` and
    :func:`hapid.pipeline.fit_for_control` (relative weights, 40 Hz band by default; a fit
    whose inverse-model controller would be improper or marginal is refitted with
    ``pd_eps = PD_EPS`` unless ``boundary_refit`` is false, ``hapid posterior
    --keep-boundary``), so the posterior is built around the model ``hapid fit`` writes for
    the same FRF. ``fit_options`` are the pipeline's NLS options (``weight``, ``solver``,
    ``omega_c_hz``, ``max_steps``, ``f_max_hz``…). The draws' diagnostics record the fit:
    ``fit_pd_eps`` (the refit's floor, 0 without a refit), ``fit_theta`` (its θ, in the
    samples' scale: ``theta_to_model(fit_theta, scale)`` is the model) and ``fit_fixed``
    (the matrices held).

    ``method``: ``"emcee"`` (default; ``n_steps`` None = run to 50 τ) or ``"laplace"``
    (``n_samples`` draws of the posterior's Laplace Gaussian in matrix coordinates, projected
    onto the PSD cone: :func:`posterior_laplace_samples`); ``posterior_options`` go to
    ``make_log_posterior`` (its ``f_max_hz`` defaults to the fit's; ``model_error="gp"`` uses
    the NLS fit as the GP amplitudes' reference and as the start of the hyperparameters' mode
    search, ``gp_hyper`` ``"map"`` by default); with ``fix_boundary`` the fit's matrices at
    the PSD boundary are held fixed (:func:`boundary_fixed`) — after a refit those are the
    refit's strictly PD matrices (``L Lᵀ + pd_eps·I``, whose ``L Lᵀ`` part is on the
    boundary), so every draw keeps the refit's realizable controller there;
    ``sampler_options`` (``n_walkers``, ``moves``, ``max_steps``…) to ``sample_posterior``.
    Returns the :class:`PosteriorSamples`.
    """
    from ..io import load_frf, save_samples
    from ._laplace import posterior_laplace_samples
    from ._likelihood import boundary_fixed
    from ._loopgp import measured_data
    from ._posterior import make_log_posterior
    from ._sampler import sample_posterior

    if method not in ("emcee", "laplace"):
        raise ValueError(f"method must be 'emcee' or 'laplace', got {method!r}")
    frf = load_frf(frf_path)
    fit_options = {"weight": "relative", "f_max_hz": FIT_BAND_HZ} | dict(fit_options or {})
    nls, refit = posterior_fit(frf, boundary_refit=boundary_refit, **fit_options)
    popts = {"f_max_hz": fit_options["f_max_hz"]} | dict(posterior_options or {})
    if fix_boundary and nls.boundary and "fixed" not in popts:
        popts["fixed"] = boundary_fixed(nls)
    if popts.get("model_error") in ("gp", "gp_corr"):
        popts.setdefault("reference", nls)
    post = make_log_posterior(frf, nls.scale, **popts)
    if method == "laplace":
        ps = posterior_laplace_samples(post, int(n_samples), nls, key=seed)
    else:
        ps = sample_posterior(post, nls, n_steps=n_steps, seed=seed, progress=progress,
                              backend_path=backend_path, **dict(sampler_options or {}))  # fmt: skip
    fit_diag = {"fit_pd_eps": 0.0 if refit is None else float(refit),
                "fit_theta": np.asarray(nls.theta),
                "fit_fixed": np.asarray(sorted(popts.get("fixed") or ()), dtype=str)}  # fmt: skip
    ps = dataclasses.replace(ps, measured=measured_data(frf), diagnostics=ps.diagnostics | fit_diag)
    save_samples(out_path, ps)
    return ps


def posterior_fit(
    frf, *, f_max_hz: float | None = FIT_BAND_HZ, boundary_refit: bool = True, **options
):
    """``(nls, refit_pd_eps)``: the fit :func:`posterior_from_files` builds the posterior
    around — ``hapid fit``'s NLS fit, by the same call: ``frf`` cut to ``0–f_max_hz`` (Hz)
    and :func:`hapid.pipeline.fit_for_control` (``options``: its NLS options; the
    PSD-boundary refit unless ``boundary_refit`` is false). ``nls`` is the
    :class:`~hapid.fit.NLSResult` (``FitFailedError`` if it did not converge)."""
    from ..pipeline import fit_for_control

    band = frf if f_max_hz is None else frf.band(0.0, float(f_max_hz))  # as hapid fit cuts it
    f, refit = fit_for_control(band, boundary_refit=boundary_refit, f_max_hz=None, **options)
    return f.result.raise_if_failed(), refit


DRAWS = ("auto", "loop_gp", "params")


def resolve_draws(draws: str, measured) -> str:
    """The draw family ``"loop_gp"`` or ``"params"`` that ``draws`` (one of :data:`DRAWS`)
    names, given the measured FRF (``None``: not known): ``"auto"`` is ``"loop_gp"`` when an
    FRF is known, else ``"params"``; ``"loop_gp"`` without an FRF is a ``ValueError``. The one
    rule of ``hapid robust`` and ``hapid tune``."""
    if draws not in DRAWS:
        raise ValueError(f"draws must be one of {DRAWS}, got {draws!r}")
    kind = draws if draws != "auto" else ("loop_gp" if measured is not None else "params")
    if kind == "loop_gp" and measured is None:
        raise ValueError("loop draws need the measured FRF: give an FRF file, or a samples file "
                         "written by hapid posterior (it stores the FRF)")  # fmt: skip
    return kind


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
    max_samples: int = 1000,
    device=None,
    n_subjects: int = 0,
    pose_offsets=(),
    metrics=(),
    seed: int = 0,
    ts: float | None = None,
) -> dict:
    """Samples file and/or measured FRF + nominal model file → robust-check summary (and
    optional JSON file).

    The controller is ``g Ẑ_T Ẑ_H⁻¹`` of the model file (``g`` default the paper's). ``draws``:

    - ``"loop_gp"``: ``max_samples`` draws of the loop ``Q = P P̂⁻¹`` conditioned on the whole
      measured FRF (:func:`hapid.uncertainty.loop_gp_check`) — the FRF of ``frf_path``, else
      the one a samples file from ``hapid posterior`` stores (``PosteriorSamples.measured``);
    - ``"params"``: the posterior samples' own second-order plants (at most ``max_samples``):
      parameter uncertainty only, not calibrated where the model class is wrong (delay,
      unmodeled modes: benchmarks/calibrate_robust.py);
    - ``"auto"`` (default): ``"loop_gp"`` when a measured FRF is known, else ``"params"``.

    With ``device`` (a preset name, e.g. ``"cu5"``, or a device), the device-based check (nominal device,
    ``pose_offsets`` (dx, dy, dz) m, ``n_subjects`` virtual subjects) is added under
    ``"device"``. ``metrics``: as :func:`robust_check` (``"all"``: also the disk margin and
    the peak of σ̄(T); default: verdict, bandwidth and loci margins only — the others are
    ``None``). Returns ``{"posterior": summary | {"draws": …}, "device": summary | None}``;
    ``"draws"`` says which family was checked (and for ``loop_gp`` the GP, the measured band
    and whether the loop gain above it is small enough for the draws to cover it).
    Every summary carries the three-valued ``verdict`` (``"passed"``, ``"failed"``, ``"not
    established"``) with its ``reason`` and ``remedy`` (:attr:`RobustReport.check`) and the
    ``loop`` it was checked on. ``ts`` (s): the rate the controller runs at for the loop
    draws (default: the device's with ``device``, else the continuous-time controller).
    """
    from ..control import Compensator
    from ..io import load_frf, load_model, load_samples, save_json
    from ._loopgp import loop_gp_check
    from ._robust import device_plants, posterior_omega, robust_check

    if draws not in DRAWS:  # before any file is read
        raise ValueError(f"draws must be one of {DRAWS}, got {draws!r}")
    model = load_model(model_path)
    ps = None if samples_path is None else load_samples(samples_path, n=model.n)
    measured = load_frf(frf_path) if frf_path is not None else getattr(ps, "measured", None)
    kind = resolve_draws(draws, measured)
    g = Compensator.paper() if g is None else g
    if kind == "loop_gp":
        n_meas = np.shape(measured["Z_H"] if isinstance(measured, dict) else measured.Z_H)[-1]
        if n_meas != model.n:
            raise ValueError(
                f"the measured FRF is for n = {n_meas} rods, the model for n = {model.n}"
            )
        if ts is None and device is not None:
            from ..device import preset

            ts = (preset(device) if isinstance(device, str) else device).ts
        rep, info = loop_gp_check(measured, model, g, n_draws=max_samples, seed=seed, gm_db=gm_db,
                                  pm_deg=pm_deg, metrics=metrics, ts=ts)  # fmt: skip
        post = rep.summary() | {"draws": info}
    else:
        if ps is None:
            raise ValueError("the robust check on parameter draws needs a samples file")
        rep = robust_check(ps, (model, g), posterior_omega(), gm_db=gm_db, pm_deg=pm_deg,
                           max_samples=max_samples, metrics=metrics, seed=seed)  # fmt: skip
        post = dataclasses.replace(rep, loop="continuous-time controller, second-order parameter draws",
                                   uncovered=PARAMS_UNCOVERED).summary()  # fmt: skip
        post["draws"] = {"draws": "params", "note": PARAMS_NOTE}
    out = {"posterior": post, "device": None}
    if device is not None:
        from ..device import preset

        dev = preset(device) if isinstance(device, str) else device
        poses = [dev.pose.moved(*o) for o in pose_offsets]
        # the sampled controller (as analyze/paper/tune close the loop with the device) on a
        # grid to fs/2, refined crossings: the nominal row is the single analysis's numbers
        from .. import pipeline
        from .._grids import nyquist_grid

        omega = nyquist_grid(dev.fs_hz)
        labels, P = device_plants(dev, omega, poses=poses, n_subjects=n_subjects)
        ctrl = pipeline.controller(model, g, ts=dev.ts)
        rep = robust_check(P, np.asarray(ctrl.response(omega)), omega,
                           controller_rhp=int(ctrl.p_rhp), gm_db=gm_db, pm_deg=pm_deg,
                           labels=labels, backend="metrics", metrics=metrics)  # fmt: skip
        out["device"] = dataclasses.replace(rep, loop=f"controller sampled at {dev.fs_hz:g} Hz, "
                                            "the device's true plants").summary()  # fmt: skip
    if out_json is not None:
        save_json(out_json, out)
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
    """Markdown table of robust-check summaries of several controllers (``{label: output of
    robust_from_files}``): one row per controller and batch (posterior, device); "—": not
    computed (``metrics``)."""
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
            sm = res.get(batch)
            if sm is None:
                continue
            vals = ["—" if sm[key] is None else fmt.format(sm[key]) for _, key, fmt in cols]
            lines.append(f"| {label} | {batch} | {sm['n']} | " + " | ".join(vals) + " |")
    return "\n".join(lines)
